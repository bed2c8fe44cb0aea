"""End to end as deployed in docker-compose.yml: the camera's office flight (uav1) feeds the localizer
process, whose published ``pose/pf`` converges onto the simulated truth."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from common.sim.scene import default_flight
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import PoseEstimate
from services.runtime.transport import open_session, zbytes
from services.tools.up import LocalCluster
from tests.integration.cluster_helpers import two_by_two

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

FRAMES = 120


def test_office_camera_process_drives_the_localizer_process_onto_the_truth(tmp_path: Path) -> None:
    poses: list[PoseEstimate] = []
    lock = threading.Lock()

    def on_pose(sample: object) -> None:
        message = decode(zbytes(sample.payload), zbytes(sample.attachment), PoseEstimate)  # type: ignore[attr-defined]
        with lock:
            poses.append(message)

    with LocalCluster(two_by_two(workers=1), tmp_path / "logs") as cluster:
        cluster.start_router()
        cluster.spawn(
            "localizer/localizer/0", ["localizer", *cluster.transport_args(), "--uav", "uav1", "--use-vo"]
        )
        cluster.wait_alive({"localizer/localizer/0"})
        with open_session(cluster.observer_transport()) as session:
            subscriber = session.declare_subscriber(keys.pose_pf_key("uav1"), on_pose)
            camera = cluster.spawn(
                "camera/office/0",
                [
                    "camera",
                    *cluster.transport_args(),
                    "--node",
                    "office",
                    "--uav",
                    "uav1",
                    "--flight",
                    "office",
                    "--frames",
                    str(FRAMES),
                    "--fps",
                    "10",
                    "--wait-master",
                    "0",
                ],
            )
            camera.wait(FRAMES / 10 + 60)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:  # the last frames' poses
                with lock:
                    if poses and poses[-1].seq >= FRAMES - 1:
                        break
                time.sleep(0.05)
            subscriber.undeclare()
    assert camera.returncode == 0
    with lock:
        received = list(poses)
    assert len(received) >= FRAMES // 2, f"only {len(received)} poses for {FRAMES} frames"
    truth = default_flight(n_frames=FRAMES).states
    late = [p for p in received if p.seq >= FRAMES - 20]
    assert late, "no pose for the last 20 frames"
    errors_m = [float(np.linalg.norm(p.p_world_body_m - truth[p.seq, :3])) for p in late]
    assert max(errors_m) < 0.10, errors_m
    assert all(p.source == "pf" and np.all(np.isfinite(p.covariance)) for p in late)
