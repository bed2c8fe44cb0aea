"""The filter's side of the coupling (:mod:`common.estimation.filter_side`): a range, yaw or frame stamped
between two IMU samples meets the state carried to its own stamp, and carrying it there does not change
what the next IMU sample integrates."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from common.estimation.coupling_types import CouplingSettings
from common.estimation.eskf_state import BiasEkfState
from common.estimation.filter_side import FilterSide
from common.estimation.measurements import ImuMeasurement
from common.estimation.tilt import ManoeuvreTrack
from common.geometry import euler_from_quaternion

GRAVITY_M_S2 = 9.80665
IMU_PERIOD_S = 0.01  # 100 Hz: the rate at which a state one sample old was furthest from a frame's stamp


def _side(**kwargs: object) -> FilterSide:
    options: dict[str, object] = {"accel_wait_for_vo_s": 0.0, **kwargs}
    return FilterSide(CouplingSettings(**options), None, Counter())  # type: ignore[arg-type]


def _level_sample(stamp_s: float, gyro: tuple[float, float, float]) -> ImuMeasurement:
    return ImuMeasurement(stamp_s, np.array(gyro), np.array([0.0, 0.0, GRAVITY_M_S2]))


def test_a_frame_between_imu_samples_meets_the_attitude_at_its_stamp_regression() -> None:
    """Regression (IMU rates): a frame, range or yaw was applied to the state of the last IMU sample before
    it. Rolling at 45 deg/s, a frame 6 ms after a 100 Hz sample was rectified with a roll 0.27 deg old."""
    roll_rate = math.radians(45.0)
    side = _side()
    track = ManoeuvreTrack()
    side.on_imu(_level_sample(0.0, (roll_rate, 0.0, 0.0)), track)
    side.on_imu(_level_sample(IMU_PERIOD_S, (roll_rate, 0.0, 0.0)), track)
    assert side.state is not None
    roll_at_sample = float(euler_from_quaternion(side.state.q_world_body)[0])
    frame_s = IMU_PERIOD_S + 0.006
    side.carry_to(frame_s, _level_sample(2 * IMU_PERIOD_S, (roll_rate, 0.0, 0.0)))
    assert side.state.stamp_s == frame_s
    roll_at_frame = float(euler_from_quaternion(side.state.q_world_body)[0])
    assert math.isclose(roll_at_frame - roll_at_sample, roll_rate * 0.006, rel_tol=1e-4)
    assert side.view().roll_rad == roll_at_frame


def test_the_state_is_not_carried_past_a_stalled_imu() -> None:
    side = _side()
    track = ManoeuvreTrack()
    side.on_imu(_level_sample(0.0, (0.0, 0.0, 0.0)), track)
    side.on_imu(_level_sample(IMU_PERIOD_S, (0.0, 0.0, 0.0)), track)
    side.carry_to(IMU_PERIOD_S + 0.5, None)  # no next sample and half a second since the last: stalled
    assert side.state is not None and side.state.stamp_s == IMU_PERIOD_S
    assert side.counters["carry_beyond_imu"] == 1
    side.carry_to(IMU_PERIOD_S + 0.004, None)  # within one interval, the next not come yet: held rates
    assert side.state.stamp_s == IMU_PERIOD_S + 0.004


magnitudes = st.floats(-3.0, 3.0)
forces = st.floats(-4.0, 4.0)
shares = st.lists(st.floats(0.05, 0.95), min_size=1, max_size=3, unique=True)


def _stopped_and_plain(
    samples: list[ImuMeasurement], stops: list[float], next_known: bool
) -> list[FilterSide]:
    """Two filter sides fed ``samples``; the first also carried to the ``stops`` (shares of the last
    interval) before the last sample, with that sample known or not (held rates)."""
    track = ManoeuvreTrack()
    # no accelerometer update (waiting for the VO's track): a difference in the prediction must show
    sides = [_side(accel_wait_for_vo_s=60.0), _side(accel_wait_for_vo_s=60.0)]
    for side in sides:
        for sample in samples[:-1]:
            side.on_imu(sample, track)
    last, ahead = samples[-2].stamp_s, samples[-1]
    for share in sorted(stops):
        sides[0].carry_to(last + share * (ahead.stamp_s - last), ahead if next_known else None)
    for side in sides:
        side.on_imu(ahead, track)
    return sides


@settings(max_examples=40, deadline=None)
@given(
    axis=st.tuples(forces, forces, forces).filter(lambda v: math.hypot(*v) > 0.1),
    rates=st.lists(magnitudes, min_size=3, max_size=3),
    stops=shares,
    next_known=st.booleans(),
)
def test_carrying_into_an_interval_leaves_the_next_samples_attitude_as_it_was(
    axis: tuple[float, float, float], rates: list[float], stops: list[float], next_known: bool
) -> None:
    """About one axis (turns that commute), the pieces carried and the rest of the interval integrate to the
    interval's trapezoid, interpolated or held: after the next IMU sample the attitude is the one it would
    have been without the stops (to the first-order kinematics' rounding, under 1e-5 rad)."""
    unit = np.array(axis) / math.hypot(*axis)
    samples = [_level_sample(k * IMU_PERIOD_S, tuple(rate * unit)) for k, rate in enumerate(rates)]
    stopped, plain = _stopped_and_plain(samples, stops, next_known)
    assert stopped.state is not None and plain.state is not None
    assert stopped.state.stamp_s == plain.state.stamp_s
    dot = abs(float(np.dot(stopped.state.q_world_body, plain.state.q_world_body)))
    assert 2.0 * math.acos(min(1.0, dot)) < 1e-5


@settings(max_examples=40, deadline=None)
@given(
    force=st.lists(st.tuples(forces, forces, forces), min_size=3, max_size=3),
    stops=shares,
    next_known=st.booleans(),
)
def test_carrying_into_an_interval_leaves_the_next_samples_velocity_as_it_was(
    force: list[tuple[float, float, float]], stops: list[float], next_known: bool
) -> None:
    """Without turning, the specific force integrated over the pieces and the rest is the interval's
    trapezoid: the velocity after the next sample is the same; the position and the covariance differ
    only by the finer steps (the trapezoid of the velocity, the ``dt^2`` noise terms)."""
    gravity = np.array([0.0, 0.0, GRAVITY_M_S2])
    samples = [
        ImuMeasurement(k * IMU_PERIOD_S, np.zeros(3), np.array(f) + gravity) for k, f in enumerate(force)
    ]
    stopped, plain = _stopped_and_plain(samples, stops, next_known)
    assert isinstance(stopped.state, BiasEkfState) and isinstance(plain.state, BiasEkfState)
    assert np.allclose(stopped.state.v_xy_m_s, plain.state.v_xy_m_s, rtol=0.0, atol=1e-12)
    assert math.isclose(stopped.state.vz_m_s, plain.state.vz_m_s, rel_tol=0.0, abs_tol=1e-12)
    # the velocity's trapezoid over the pieces against the whole interval's: within dt^2 times the change
    change = float(np.linalg.norm(np.subtract(force[2], force[1])))
    assert np.all(np.abs(stopped.state.p_xy_m - plain.state.p_xy_m) <= IMU_PERIOD_S**2 * change + 1e-12)
    std = np.sqrt(np.diag(plain.state.covariance))
    assert np.all(np.abs(stopped.state.covariance - plain.state.covariance) <= 0.01 * np.outer(std, std))
