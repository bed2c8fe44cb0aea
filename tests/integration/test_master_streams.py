"""The master against hostile frames and its own death: refused and counted, the yaw unharmed and continued.

Frames of paper A's hover go to uav0's camera key from the test; between them, hostile frames (seq 2**53, a
future stamp, another UAV's frame, 64x64 and 4096x4096 frames), then a camera restart from seq 0. Then two
masters for one UAV: exactly one publishes; the active one is SIGKILLed and the standby continues the yaw.
"""

from __future__ import annotations

import itertools
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from common.sim.flight import hover_flight
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import Frame, Health, YawEstimate
from services.runtime.transport import open_session, zbytes
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.up import LocalCluster
from tests.integration.cluster_helpers import reference_yaw_rad

pytestmark = [pytest.mark.zenoh]

N = 100
FPS = 25.0


class Yaws:
    """Every yaw published on uav0's key, duplicates included."""

    def __init__(self, session: zenoh.Session) -> None:
        self.items: list[YawEstimate] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(keys.yaw_key("uav0"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.items.append(decode(zbytes(sample.payload), zbytes(sample.attachment), YawEstimate))

    def by_seq(self) -> dict[int, list[YawEstimate]]:
        with self._lock:
            out: dict[int, list[YawEstimate]] = {}
            for y in self.items:
                out.setdefault(y.seq, []).append(y)
            return out

    def wait(self, condition: object, timeout_s: float = 20.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():  # type: ignore[operator]
                return True
            time.sleep(0.05)
        return False


def reported_drops(published: dict[int, list[YawEstimate]]) -> int:
    """Latest-wins drops the masters reported (each master counts from 0)."""
    total = previous = 0
    for seq in sorted(published):
        dropped = published[seq][0].dropped_frames
        total += dropped - previous if dropped >= previous else dropped
        previous = dropped
    return total


def leaders(session: zenoh.Session) -> list[str]:
    replies = session.liveliness().get(keys.election_all("uav0"), timeout=2.0)
    return [str(r.ok.key_expr) for r in replies if r.ok is not None and "/leader/" in str(r.ok.key_expr)]


def one_leader(session: zenoh.Session, yaws: Yaws) -> str:
    """The one leader's token, asked until exactly one answers, and that answer kept.

    Regression (CI, once): a test waited for one leader, then asked again to read it, and the second
    liveliness get came back empty; each get is a fresh query that can miss a token that is there."""
    found: list[str] = []

    def single() -> bool:
        found[:] = leaders(session)
        return len(found) == 1

    assert yaws.wait(single), "no master took the lead"
    return found[0]


def spec() -> ClusterSpec:
    return ClusterSpec(name="streams", hosts=(HostSpec(name="h1", workers=1),))


def frame(uav: str, seq: int, stamp_s: float, pixels: np.ndarray) -> tuple[bytes, bytes]:
    h, w = pixels.shape
    return encode(Frame(uav=uav, seq=seq, stamp_s=stamp_s, width=w, height=h, pixels=pixels))


def health(session: zenoh.Session, role: str, node: str) -> Health:
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        replies = list(session.get(keys.health_key(role, node, 0), timeout=5.0))
        if replies and replies[0].ok is not None:
            sample = replies[0].ok
            return decode(zbytes(sample.payload), zbytes(sample.attachment), Health)
    raise AssertionError(f"{role}/{node} did not answer")


@pytest.fixture(scope="module")
def flight_frames() -> tuple[list[np.ndarray], np.ndarray]:
    flight = hover_flight(seed=0, n_frames=N)
    return [flight.frame(k) for k in range(N)], reference_yaw_rad(N)


def test_hostile_frames_are_refused_counted_and_the_yaw_stays_exact(
    tmp_path: Path, flight_frames: tuple[list[np.ndarray], np.ndarray]
) -> None:
    frames, reference = flight_frames
    with LocalCluster(spec(), tmp_path / "logs") as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        with open_session(cluster.observer_transport()) as session:
            yaws = Yaws(session)
            pub = session.declare_publisher(
                keys.camera_key("uav0"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            one_leader(session, yaws)
            rng = np.random.default_rng(0)
            hostile = [
                frame("uav0", 2**53, 30 / FPS, frames[30]),  # seq jump
                frame("uav0", 31, 1e5, frames[31]),  # stamp jump
                frame("uav1", 31, 31 / FPS, rng.integers(0, 255, frames[0].shape, dtype=np.uint8)),
                frame("uav0", 31, 31 / FPS, rng.integers(0, 255, (64, 64), dtype=np.uint8)),
                frame("uav0", 31, 31 / FPS, rng.integers(0, 255, (4096, 4096), dtype=np.uint8)),
            ]
            for k in range(60):
                if 30 <= k < 30 + len(hostile):
                    bad_payload, bad_attachment = hostile[k - 30]
                    pub.put(bad_payload, attachment=bad_attachment)
                payload, attachment = frame("uav0", k, k / FPS, frames[k])
                pub.put(payload, attachment=attachment)
                time.sleep(1 / FPS)
            # the camera restarts: seq from 0 again, the flight goes on
            for k in range(60, N):
                payload, attachment = frame("uav0", k - 60, k / FPS, frames[k])
                pub.put(payload, attachment=attachment)
                time.sleep(1 / FPS)
            assert yaws.wait(lambda: N - 60 - 3 in yaws.by_seq() and 59 in yaws.by_seq())
            counters = health(session, "master", "master").counters
    assert counters.get("refused_camera_seq_jump", 0) >= 1
    assert counters.get("refused_camera_stamp_jump", 0) >= 1
    assert counters.get("refused_camera_foreign_uav", 0) == 1
    assert counters.get("refused_camera_wrong_size", 0) == 2
    assert counters.get("epochs", 0) == 2, counters
    first_epoch = {y.seq: y for y in yaws.items if y.stamp_s < 60 / FPS}
    second_epoch = {y.seq + 60: y for y in yaws.items if y.stamp_s >= 60 / FPS}
    assert 2**53 not in first_epoch and all(y.uav == "uav0" for y in yaws.items)
    # every real frame before the restart that got a yaw has the in-process core's yaw, hostile ones or not
    measured = [k for k in range(1, 60) if k in first_epoch]
    assert 59 - len(measured) <= first_epoch[59].dropped_frames  # only latest-wins drops (busy host)
    for k in measured:  # exact where the frame before was measured too (else a longer pair, within 0.1 deg)
        tolerance = 1e-9 if k - 1 in first_epoch else np.radians(0.1)
        y = first_epoch[k]  # what a failure needs to be diagnosed (one inexact frame under heavy load, once)
        why = (k, y.method, y.provenance, y.patch_count, y.inlier_count, y.redispatched, y.members)
        assert y.yaw_rad == pytest.approx(reference[k], abs=tolerance), why
    # the restart is a new epoch whose yaw continues from the last one (no reset to 0)
    start = min(second_epoch)
    assert start == 60 + 2  # confirmed by its third frame
    assert second_epoch[start].method == "initial"
    assert second_epoch[start].yaw_rad == pytest.approx(first_epoch[59].yaw_rad, abs=1e-12)
    for k in sorted(second_epoch)[1:]:
        expected = first_epoch[59].yaw_rad + reference[k] - reference[start]
        assert second_epoch[k].yaw_rad == pytest.approx(expected, abs=np.radians(0.2)), k


def test_one_active_master_and_a_standby_that_continues_the_yaw_when_it_is_killed(
    tmp_path: Path, flight_frames: tuple[list[np.ndarray], np.ndarray]
) -> None:
    frames, reference = flight_frames
    with LocalCluster(spec(), tmp_path / "logs") as cluster:
        cluster.start(with_master=False)
        masters = {}
        for node in ("ma", "mb"):
            name = f"master/{node}/0"
            cluster.spawn(name, ["master", *cluster.transport_args(), "--node", node, "--uav", "uav0"])
            masters[node] = name
        cluster.wait_alive({*masters.values(), "worker/h1/0", "foreman/h1/0"})
        with open_session(cluster.observer_transport()) as session:
            yaws = Yaws(session)
            pub = session.declare_publisher(
                keys.camera_key("uav0"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            one_leader(session, yaws)
            for k in range(N):
                if k == 40:
                    leader = one_leader(session, yaws)
                    active = "ma" if "/leader/ma/" in leader else "mb"
                    cluster.signal(masters[active], signal.SIGKILL)
                if k == 70:  # the killed master comes back: it must stand by
                    cluster.spawn(
                        masters[active],
                        ["master", *cluster.transport_args(), "--node", active, "--uav", "uav0"],
                    )
                payload, attachment = frame("uav0", k, k / FPS, frames[k])
                pub.put(payload, attachment=attachment)
                time.sleep(1 / FPS)
            assert yaws.wait(lambda: N - 1 in yaws.by_seq())
    published = yaws.by_seq()
    duplicates = {k: len(v) for k, v in published.items() if len(v) > 1}
    assert not duplicates, f"frames published by two masters: {duplicates}"
    missing = [k for k in range(N) if k not in published]
    assert len(missing) <= 1 + reported_drops(published), (
        f"frames without a yaw across the fail-over: {missing}"
    )
    for k, (y,) in published.items():
        if k > 0:
            assert y.yaw_rad == pytest.approx(reference[k], abs=np.radians(1.0)), (k, y.method)
    # the standby continues the yaw's variance too (it restarted at 0: a regression of the rig test's kind)
    variances = [published[k][0].yaw_variance_rad2 for k in sorted(published)]
    assert all(later >= earlier for earlier, later in itertools.pairwise(variances))


def test_forged_yaw_before_a_takeover_does_not_move_the_standbys_starting_yaw(
    tmp_path: Path, flight_frames: tuple[list[np.ndarray], np.ndarray]
) -> None:
    """Open profile: a forger re-publishes the last frames' yaw (right seq and stamp, 2 rad off) just before
    the active master dies. The standby keeps only yaw of the session that answered as the active master,
    so it continues from the real yaw and counts the forged ones (``yaw_untrusted``)."""
    frames, reference = flight_frames
    takeover = 40
    with LocalCluster(spec(), tmp_path / "logs") as cluster:
        cluster.start(with_master=False)
        masters = {}
        for node in ("ma", "mb"):
            masters[node] = f"master/{node}/0"
            cluster.spawn(
                masters[node], ["master", *cluster.transport_args(), "--node", node, "--uav", "uav0"]
            )
        cluster.wait_alive({*masters.values(), "worker/h1/0", "foreman/h1/0"})
        with (
            open_session(cluster.observer_transport()) as session,
            open_session(cluster.observer_transport()) as forger,
        ):
            yaws = Yaws(session)
            pub = session.declare_publisher(
                keys.camera_key("uav0"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            leader = one_leader(session, yaws)
            active = "ma" if "/leader/ma/" in leader else "mb"
            standby = "mb" if active == "ma" else "ma"
            forged_yaw = forger.declare_publisher(keys.yaw_key("uav0"))
            for k in range(N):
                if k == takeover:
                    assert yaws.wait(lambda: takeover - 1 in yaws.by_seq())
                    for seq in range(takeover - 5, takeover):
                        payload, attachment = encode(
                            YawEstimate(
                                uav="uav0", seq=seq, stamp_s=seq / FPS, delta_yaw_rad=0.0,
                                yaw_rad=reference[seq] + 2.0, inlier_count=40, patch_count=40,
                                confidence=1.0, low_confidence=False, method="patches",
                            )
                        )  # fmt: skip
                        forged_yaw.put(payload, attachment=attachment)
                    assert yaws.wait(
                        lambda: health(session, "master", standby).counters.get("yaw_untrusted", 0) >= 5
                    ), "the standby did not refuse the forged yaw"
                    cluster.signal(masters[active], signal.SIGKILL)
                payload, attachment = frame("uav0", k, k / FPS, frames[k])
                pub.put(payload, attachment=attachment)
                time.sleep(1 / FPS)
            assert yaws.wait(lambda: N - 1 in yaws.by_seq())
    published = yaws.by_seq()
    after = [k for k in range(takeover, N) if k in published]
    assert len(after) >= N - takeover - 2, f"frames without a yaw after the take-over: {after}"
    for k in after:
        (y,) = published[k]
        assert y.yaw_rad == pytest.approx(reference[k], abs=np.radians(1.0)), (k, y.method)
