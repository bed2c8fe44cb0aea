"""The field flight through a cluster: the master's gyro prior (from the camera's IMU samples) and lens model
(a calibration file) give the in-process core's yaw, to 1e-9 deg, with each estimate's provenance."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from common.datasets.calibration import opencv_yaml_text
from common.provenance import Provenance
from common.sim.field import field_flight
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Stats
from common.yaw import YawSettings, YawTracker, gyro_delta_yaw_rad, make_patch_grid
from services.runtime.transport import open_session, zbytes
from services.tools.observe import YawCollector
from services.tools.up import LocalCluster
from tests.integration.cluster_helpers import two_by_two

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

FRAMES = 60


def _in_process(n: int) -> tuple[np.ndarray, list[Provenance]]:
    flight = field_flight("field", seed=0, n_frames=n)
    settings = YawSettings(camera=flight.camera)
    tracker = YawTracker(settings, make_patch_grid(flight.camera.shape, settings))
    stamps = flight.frame_stamps_s
    state = tracker.initial_state(flight.frame(0), stamp_s=float(stamps[0]))
    yaw, provenance = [0.0], [Provenance.INITIAL]
    for k in range(1, n):
        gyro = gyro_delta_yaw_rad(flight.imu.stamps_s, flight.imu.gyro_rad_s, stamps[k - 1], stamps[k])
        state, estimate = tracker.track(state, flight.frame(k), float(stamps[k]), gyro)
        yaw.append(estimate.yaw_rad)
        provenance.append(estimate.provenance)
    return np.array(yaw), provenance


def test_field_flight_through_the_cluster_equals_the_in_process_core_with_gyro_and_lens(
    tmp_path: Path,
) -> None:
    calibration = tmp_path / "field.yaml"
    calibration.write_text(opencv_yaml_text(field_flight("field", n_frames=2).camera))
    expected_yaw, expected_provenance = _in_process(FRAMES)
    spec = two_by_two(topology="master-worker", workers=1)
    with LocalCluster(spec, tmp_path / "logs", master_args=("--calibration", str(calibration))) as cluster:
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
                ["--flight", "field", "--frames", str(FRAMES), "--fps", "0", "--in-flight", "1"]
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
    assert sorted(estimates) == list(range(FRAMES))
    yaw = np.array([estimates[k].yaw_rad for k in range(FRAMES)])
    assert np.degrees(np.abs(yaw - expected_yaw)).max() <= 1e-9
    assert [estimates[k].provenance for k in range(FRAMES)] == expected_provenance
    assert all(estimates[k].yaw_variance_rad2 > 0.0 for k in range(1, FRAMES))
