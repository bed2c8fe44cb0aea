"""Field nuisances of the simulator: bursty frame stamps, dropped frames, a mounted camera, an IMU with its
own axes and clock; deterministic by seed, the truth exact at every stamp."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.estimation.measurements import FrameMeasurement, ImuMeasurement
from common.geometry import R_BODY_CAMERA_DOWN, matrix_from_euler
from common.sim.field import BURSTY_NO_IMU, FIELD_SCENARIOS, MOUNTED_RIG, mounted_camera
from common.sim.flight import MIN_FRAME_GAP_S, frame_stamps, hover_flight, simulate_flight
from common.sim.sensors import ImuNoise
from common.sim.stream import flight_measurements
from common.sim.trajectory import hover_trajectory


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(2, 400),
    seed=st.integers(0, 2**31),
    jitter=st.floats(0.0, 0.06),
    share=st.floats(0.0, 0.2),
)
def test_bursty_stamps_keep_order_and_their_share_of_drops(
    n: int, seed: int, jitter: float, share: float
) -> None:
    stamps = frame_stamps(n, 20.0, seed, jitter, share)
    assert np.array_equal(stamps, frame_stamps(n, 20.0, seed, jitter, share))  # deterministic by seed
    assert stamps[0] == 0.0
    assert stamps.size == n - round(share * max(n - 2, 0))
    assert np.all(np.diff(stamps) >= MIN_FRAME_GAP_S - 1e-12)
    # every stamp within the jitter (plus the order's push of at most one gap per frame) of the nominal span
    assert stamps[-1] <= (n - 1) / 20.0 + jitter + MIN_FRAME_GAP_S * stamps.size


def test_without_nuisances_the_stamps_are_exact_multiples() -> None:
    assert np.array_equal(frame_stamps(5, 20.0, 3), np.arange(5) / 20.0)
    with pytest.raises(InputError):
        frame_stamps(5, 20.0, 0, jitter_s=-0.1)
    with pytest.raises(InputError):
        frame_stamps(5, 20.0, 0, drop_share=0.6)


def test_jitter_of_40_ms_makes_bursts_of_short_and_long_gaps() -> None:
    stamps = frame_stamps(600, 20.0, 0, 0.04, 0.05)
    gaps = np.diff(stamps)
    assert gaps.min() < 0.015 and gaps.max() > 0.09  # bursty: 8-92 ms on the real flight of issue 26
    assert 0.8 * 0.05 < np.median(gaps) < 1.3 * 0.05


def test_the_truth_is_exact_at_the_bursty_stamps() -> None:
    trajectory = hover_trajectory(seed=1, duration_s=5.0)
    flight = simulate_flight(trajectory, seed=1, n_frames=60, frame_jitter_s=0.04, frame_drop_share=0.05)
    assert flight.n_frames == 60 - round(0.05 * 58)
    truth = trajectory.sample(flight.frame_stamps_s)
    assert np.array_equal(flight.q_world_body, truth.q_world_body)
    assert np.array_equal(flight.yaw_rad, truth.euler_rad[:, 2])


def test_an_imu_with_its_own_axes_and_clock_reads_the_body_rate_turned_and_stamped_late() -> None:
    R_body_imu = matrix_from_euler(math.pi, 0.0, math.pi / 2.0)
    flight = hover_flight(
        seed=2, n_frames=40, imu_noise=ImuNoise.ideal(), R_body_imu=R_body_imu, imu_time_offset_s=0.012
    )
    imu = flight.imu
    assert np.allclose(imu.gyro_rad_s @ R_body_imu.T, imu.true_gyro_rad_s, atol=1e-12)
    assert np.allclose(imu.accel_m_s2 @ R_body_imu.T, imu.true_accel_m_s2, atol=1e-12)
    assert imu.stamps_s[0] == pytest.approx(0.012) and imu.true_stamps_s[0] == pytest.approx(0.0)
    truth = flight.trajectory.sample(imu.true_stamps_s[:50])
    assert np.allclose(truth.omega_body_rad_s, imu.true_gyro_rad_s[:50])
    with pytest.raises(InputError, match="R_body_imu"):
        hover_flight(seed=2, n_frames=4, R_body_imu=np.diag([1.0, 1.0, -1.0]))


def test_the_stream_delivers_imu_samples_in_true_time_with_their_own_stamps() -> None:
    flight = hover_flight(seed=2, n_frames=6, imu_time_offset_s=0.012)
    events = list(flight_measurements(flight))
    frame_at = [i for i, m in enumerate(events) if isinstance(m, FrameMeasurement)]
    imu = [m for m in events if isinstance(m, ImuMeasurement)]
    assert imu[0].stamp_s == pytest.approx(0.012)
    # the IMU samples before the second frame are those of true time <= 0.05 s, stamped 12 ms later
    before = [m for m in events[frame_at[0] : frame_at[1]] if isinstance(m, ImuMeasurement)]
    assert before[-1].stamp_s == pytest.approx(0.05 + 0.012)


def test_the_mounted_camera_sees_the_ground_turned_and_tilted() -> None:
    assert np.allclose(mounted_camera(0.0, 0.0), R_BODY_CAMERA_DOWN)
    R = mounted_camera(10.0, 90.0)
    optical_axis_body = R[:, 2]
    assert math.degrees(math.acos(-optical_axis_body[2])) == pytest.approx(10.0)
    assert np.allclose(MOUNTED_RIG.R_body_camera, R)
    assert FIELD_SCENARIOS["bursty_no_imu"] is BURSTY_NO_IMU and not BURSTY_NO_IMU.use_imu
