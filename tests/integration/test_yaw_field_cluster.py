"""The field flight through a cluster: the master's gyro prior (from the camera's IMU samples) and lens model
(a calibration file) give the in-process core's yaw, to 1e-9 deg, with each estimate's provenance."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from common.datasets.calibration import opencv_yaml_text
from common.provenance import Provenance
from common.sim.field import MOUNTED_RIG, field_flight
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Stats
from common.yaw import YawSettings
from services.runtime.transport import open_session, zbytes
from services.tools.flight_prior import FlightPrior, Level
from services.tools.observe import YawCollector
from services.tools.up import LocalCluster
from tests.integration.cluster_helpers import two_by_two

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

FRAMES = 60


def _numbers(R: np.ndarray) -> str:
    return ",".join(f"{v:.17g}" for v in np.asarray(R).ravel())


#: the master's mount options of each flight (the rig's, until the stream carries it)
MOUNT_ARGS = {
    "field": (),
    "mounted_rig": (  # a matrix may start with a minus: --option=value
        f"--mount={_numbers(MOUNTED_RIG.R_body_camera)}",
        f"--imu-axes={_numbers(MOUNTED_RIG.R_body_imu)}",
        f"--imu-time-offset={MOUNTED_RIG.imu_time_offset_s:.17g}",
        "--level-views",  # and each pair in level views by the IMU's tilt
    ),
}


def _in_process(name: str, n: int) -> tuple[np.ndarray, list[Provenance]]:
    """The flight as its master measures it (:class:`~services.tools.flight_prior.FlightPrior`)."""
    flight = field_flight(name, seed=0, n_frames=n)
    prior = FlightPrior(flight, level=Level.IMU if "--level-views" in MOUNT_ARGS[name] else Level.NONE)
    tracker = prior.tracker(YawSettings())
    stamps = flight.frame_stamps_s
    state = tracker.initial_state(flight.frame(0), stamp_s=float(stamps[0]), R_level_body=prior.tilt(0))
    yaw, provenance = [0.0], [Provenance.INITIAL]
    for k in range(1, n):
        gyro, tilt = prior.gyro_delta_rad(k), prior.tilt(k)
        state, estimate = tracker.track(state, flight.frame(k), float(stamps[k]), gyro, tilt)
        yaw.append(estimate.yaw_rad)
        provenance.append(estimate.provenance)
    return np.array(yaw), provenance


#: each flight through one of the two paths (the refinement's transient jobs go to workers, or to foremen
#: that spread them over their workers)
TOPOLOGY = {"field": "master-foreman-worker", "mounted_rig": "master-worker"}


@pytest.mark.parametrize("name", sorted(MOUNT_ARGS))
def test_field_flight_through_the_cluster_equals_the_in_process_core_with_gyro_and_lens(
    tmp_path: Path, name: str
) -> None:
    """``mounted_rig``: the camera tilted and turned, the IMU in other axes and 12 ms ahead; the master told
    them by its mount options, and fitting in level views. Two thirds of the field flights' pairs turn
    enough to be measured twice: that second pass runs on the members that measured the patches, and the
    yaw still equals the core's."""
    calibration = tmp_path / "field.yaml"
    calibration.write_text(opencv_yaml_text(field_flight(name, n_frames=2).camera))
    expected_yaw, expected_provenance = _in_process(name, FRAMES)
    spec = two_by_two(topology=TOPOLOGY[name], workers=1)
    # the refinement on the members at any size (by default only from 2**17 level pixels: 40960 here)
    master_args = ("--calibration", str(calibration), "--refine-on-members-pixels", "0", *MOUNT_ARGS[name])
    with LocalCluster(spec, tmp_path / "logs", master_args=master_args) as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        with open_session(cluster.observer_transport()) as session:
            stats: list[Stats] = []
            master_stats = session.declare_subscriber(
                keys.stats_key("master", "master", 0),
                lambda s: stats.append(decode(zbytes(s.payload), zbytes(s.attachment), Stats)),
            )
            collector = YawCollector(session, "uav0")
            cluster.start_camera(
                ["--flight", name, "--frames", str(FRAMES), "--fps", "0", "--in-flight", "1"]
            )
            deadline = time.monotonic() + 120.0
            while len(collector.estimates) < FRAMES and time.monotonic() < deadline:
                collector.wait_for(FRAMES, 1.0)
            estimates = dict(collector.estimates)
            collector.close()
            deadline = time.monotonic() + 5.0  # the next stats message counts every frame
            while time.monotonic() < deadline and not (
                stats and stats[-1].counters.get("gyro_prior", 0) >= FRAMES - 1
            ):
                time.sleep(0.05)
            master_stats.undeclare()
        cluster.stop()
    assert stats and stats[-1].counters.get("gyro_prior", 0) == FRAMES - 1  # every pair had the gyro prior
    # levelled: every frame after the first 1.5 s of IMU samples (half the tilt's window), else none
    tilts = stats[-1].counters.get("tilt", 0)
    assert tilts >= FRAMES // 3 if "--level-views" in MOUNT_ARGS[name] else tilts == 0, stats[-1].counters
    refined = sum(estimates[k].method == "refined" for k in range(FRAMES))
    assert refined >= FRAMES // 3
    # each refined frame's 40 patches measured again: by the members that measured them, but for what the
    # master measured in the first pass (a new member earns its share over a few frames; on a busy host a
    # member that misses a deadline is paused and the master computes its share); a member's failed part
    # (measured by the master) stays rare: a systematic one, e.g. a foreman without the previous crops,
    # would fail every refined frame. Quiet host: 1387 of 1520 patches sent, no failure.
    counters = stats[-1].counters
    sent, here = counters.get("refine_patches_sent", 0), counters.get("refine_patches_here", 0)
    assert sent + here <= 40 * refined and sent >= 40, (sent, here)
    assert counters.get("refine_failures", 0) <= refined // 4, counters
    assert sorted(estimates) == list(range(FRAMES))
    yaw = np.array([estimates[k].yaw_rad for k in range(FRAMES)])
    assert np.degrees(np.abs(yaw - expected_yaw)).max() <= 1e-9
    assert [estimates[k].provenance for k in range(FRAMES)] == expected_provenance
    assert all(estimates[k].yaw_variance_rad2 > 0.0 for k in range(1, FRAMES))
