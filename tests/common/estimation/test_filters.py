"""One IMU sample through either filter in one call (:meth:`AttitudeFilter.imu_step`): exactly what the
predict and the accelerometer update give one after the other, and the read-outs of that state."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.estimation.coupling_types import EkfKind
from common.estimation.ekf_models import EkfError
from common.estimation.filters import make_filter
from common.geometry import quaternion_from_euler

_FILTERS = {kind: make_filter(kind) for kind in EkfKind}
_rate = st.floats(-2.0, 2.0)
_accel = st.floats(-3.0, 3.0)


@settings(max_examples=60, deadline=None)
@given(
    kind=st.sampled_from(list(EkfKind)),
    tilt=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-3.0, 3.0)),
    gyro=st.tuples(_rate, _rate, _rate),
    accel=st.tuples(_accel, _accel, _accel),
    motion=st.tuples(_accel, _accel, _accel),
    dt_s=st.floats(1e-4, 0.05),
    update=st.booleans(),
)
def test_an_imu_step_is_the_predict_then_the_accelerometer_update_bit_for_bit(
    kind: EkfKind,
    tilt: tuple[float, float, float],
    gyro: tuple[float, float, float],
    accel: tuple[float, float, float],
    motion: tuple[float, float, float],
    dt_s: float,
    update: bool,
) -> None:
    ekf = _FILTERS[kind]
    state = ekf.initial_state(quaternion_from_euler(*tilt), 2.0, 1.0)
    gyro_rad_s = np.array(gyro)
    measured = np.array(accel) + np.array([0.0, 0.0, 9.8])
    mean_accel = 0.5 * (measured + np.array([0.0, 0.0, 9.8]))  # the interval's, as the coupling passes it
    step = ekf.imu_step(state, gyro_rad_s, mean_accel, dt_s, measured if update else None, motion)

    expected = ekf.predict(state, gyro_rad_s, dt_s, mean_accel)
    accepted = None
    if update:
        result = ekf.update_accelerometer(expected, measured, motion)
        expected, accepted = result.state, result.accepted
    assert step.accepted is accepted
    assert step.state.stamp_s == expected.stamp_s
    assert np.array_equal(step.state.q_world_body, expected.q_world_body)
    assert step.state.pz_m == expected.pz_m
    assert np.array_equal(step.state.covariance, expected.covariance)
    assert np.array_equal(step.attitude_covariance_world, ekf.attitude_covariance_world(expected))
    assert step.altitude_var_m2 == ekf.altitude_variance(expected)


@pytest.mark.parametrize("kind", list(EkfKind))
def test_an_imu_step_refuses_a_bad_interval_and_a_non_finite_reading_as_input_errors(kind: EkfKind) -> None:
    ekf = _FILTERS[kind]
    state = ekf.initial_state(np.array([1.0, 0.0, 0.0, 0.0]), 1.0, 0.0)
    still = np.array([0.0, 0.0, 9.8])
    with pytest.raises(InputError, match="dt_s"):
        ekf.imu_step(state, np.zeros(3), still, -0.01, None)
    with pytest.raises(InputError, match="accel_m_s2"):
        ekf.imu_step(state, np.zeros(3), still, 0.01, np.array([0.0, np.inf, 9.8]))
    with pytest.raises(EkfError):  # a degenerate quaternion is the filter's own error
        ekf.imu_step(replace(state, covariance=state.covariance * np.nan), np.zeros(3), still, 0.01, still)
