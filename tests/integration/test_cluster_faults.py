"""A simulated run through a local cluster of real processes: a yaw for every frame, equal to in-process,
also when a foreman is SIGKILLed and a worker SIGSTOPped mid-run (the issue's "Done when")."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from services.runtime.transport import open_session
from services.tools.observe import YawCollector
from services.tools.up import LocalCluster
from tests.integration.cluster_helpers import FAULT_FRAMES, reference_yaw_rad, two_by_two

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]


def test_every_frame_yields_the_in_process_yaw_despite_a_killed_foreman_and_a_frozen_worker(
    tmp_path: Path,
) -> None:
    n = FAULT_FRAMES
    kill_at, freeze_at = int(0.35 * n), int(0.7 * n)
    reference: dict[str, np.ndarray] = {}
    worker = threading.Thread(target=lambda: reference.update(yaw=reference_yaw_rad(n)), daemon=True)
    worker.start()
    with LocalCluster(two_by_two(), tmp_path / "logs") as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        with open_session(cluster.observer_transport()) as session:
            collector = YawCollector(session, "uav0")
            cluster.start_camera(["--frames", str(n), "--fps", "0", "--in-flight", "1"])
            events: dict[str, int] = {}
            deadline = time.monotonic() + min(240.0, 30.0 + 0.1 * n)
            camera = cluster.processes["camera/camera/0"]
            while len(collector.estimates) < n and time.monotonic() < deadline:
                if camera.poll() is not None and not collector.wait_for(n, 3.0):
                    break  # the camera is done: whatever is missing now is lost
                newest = collector.newest()
                if "kill" not in events and newest >= kill_at:
                    cluster.signal("foreman/h1/0", signal.SIGKILL)
                    events["kill"] = newest
                if "freeze" not in events and newest >= freeze_at:
                    cluster.signal("worker/h2/1", signal.SIGSTOP)
                    events["freeze"] = newest
                time.sleep(0.005)
            collector.wait_for(n, 5.0)
            estimates = dict(collector.estimates)
            collector.close()
        codes = cluster.stop()
    worker.join(300.0)
    assert set(events) == {"kill", "freeze"}, events
    assert sorted(estimates) == list(range(n)), (
        f"missing frames {sorted(set(range(n)) - set(estimates))[:20]}"
    )
    yaw = np.array([estimates[k].yaw_rad for k in range(n)])
    error_deg = np.degrees(np.abs(yaw - reference["yaw"]))
    assert error_deg.max() <= 1e-9, (
        f"max |cluster - in-process| = {error_deg.max():.3g} deg at {error_deg.argmax()}"
    )
    redispatched = sum(e.redispatched for e in estimates.values())
    total_ms = np.array([estimates[k].timings_ms["total"] for k in range(1, n)])
    print(
        f"\nfault run: {n} frames, yaw for {len(estimates)}, "
        f"max |cluster - in-process| {error_deg.max():.2e} deg, "
        f"foreman/h1 SIGKILLed at frame {events['kill']}, "
        f"worker/h2/1 SIGSTOPped at frame {events['freeze']}, "
        f"{redispatched} shares re-dispatched, dropped {max(e.dropped_frames for e in estimates.values())}, "
        f"master ms/frame median {np.median(total_ms):.1f} max {total_ms.max():.1f}"
    )
    assert max(e.dropped_frames for e in estimates.values()) == 0
    # the faults really happened and were absorbed: shares were re-dispatched after the kill
    after_kill = [estimates[k] for k in range(events["kill"] + 1, n)]
    assert all("foreman/h1/0" not in e.members for e in after_kill[5:])
    # the frozen worker's share went elsewhere: re-dispatched by its foreman within the block, or (when the
    # master's deadline fired first) by the master; which one wins is a race of two 0.3 s deadlines
    # The frozen worker computed after the kill (unless paused by a missed deadline on a loaded host, as
    # every member may be: then the master or its foreman took its share, CI once at the frame before the
    # freeze), and a frame sent after the SIGSTOP never counts it: its share was computed elsewhere (the test
    # reads the newest yaw every 5 ms and the camera keeps one frame in flight: 10 frames cover that lag)
    frozen = "foreman/h2/0>worker/h2/1"
    assert any(frozen in estimates[k].members for k in range(events["kill"] + 1, events["freeze"]))
    assert all(frozen not in estimates[k].members for k in range(events["freeze"] + 10, n))
    assert codes["master/master/0"] == 0 and codes["foreman/h2/0"] == 0
