"""The paper-C EKF: models against geometry, analytic Jacobians against numerical differentiation,
invariants (unit quaternion, q0 >= 0, continuous yaw across +-180 deg), gating, and tracking of the
simulator's flight (b) from its IMU and rangefinder series."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.estimation.ekf import (
    AttitudeAltitudeEkf,
    EkfSettings,
)
from common.estimation.ekf_models import (
    accelerometer_model,
    propagate_quaternion,
    quaternion_rate_matrix,
    rangefinder_model,
    state_transition,
    yaw_model,
)
from common.geometry import (
    euler_from_quaternion,
    matrix_from_quaternion,
    quaternion_from_euler,
    quaternion_multiply,
    wrap_angle_rad,
)
from common.sim.sensors import (
    ray_ground_distance,
)
from tests.common.estimation.flight_b import run_over_flight_b

angles = st.floats(-math.pi, math.pi, allow_nan=False)
tilts = st.floats(-0.6, 0.6, allow_nan=False)
rates = st.floats(-3.0, 3.0, allow_nan=False)


def _q(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    q = quaternion_from_euler(roll, pitch, yaw)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def _numeric_jacobian(fn, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((np.asarray(fn(x + d)) - np.asarray(fn(x - d))) / (2.0 * eps))
    return np.stack(cols, axis=-1)


# ---- models and Jacobians ------------------------------------------------------------------------


@given(tilts, tilts, angles, rates, rates, rates)
def test_omega_is_the_right_product_with_the_body_rate(
    r: float, p: float, y: float, wx: float, wy: float, wz: float
) -> None:
    q = np.array(_q(r, p, y))
    expected = 0.5 * quaternion_multiply(q, [0.0, wx, wy, wz])
    assert np.allclose(0.5 * quaternion_rate_matrix([wx, wy, wz]) @ q, expected, atol=1e-12)


@given(tilts, tilts, angles, rates, rates, rates)
def test_state_transition_is_the_jacobian_of_the_propagation(
    r: float, p: float, y: float, wx: float, wy: float, wz: float
) -> None:
    dt = 0.0025
    a, b, c = 0.5 * dt * wx, 0.5 * dt * wy, 0.5 * dt * wz
    q = np.array(_q(r, p, y))
    J = _numeric_jacobian(lambda v: propagate_quaternion(tuple(v), a, b, c), q)
    F = state_transition([wx, wy, wz], dt)
    assert np.allclose(J, F[:4, :4], atol=1e-8)
    assert np.allclose(F[:4, :4], np.eye(4) + 0.5 * dt * quaternion_rate_matrix([wx, wy, wz]), atol=1e-15)
    assert F[4, 4] == 1.0 and np.all(F[4, :4] == 0.0) and np.all(F[:4, 4] == 0.0)


@given(tilts, tilts, angles, st.floats(-3, 3), st.floats(-3, 3), st.floats(5, 15))
def test_accelerometer_model_is_R_transpose_f_and_its_jacobian(
    r: float, p: float, y: float, fx: float, fy: float, fz: float
) -> None:
    q = np.array(_q(r, p, y))
    h, H = accelerometer_model(tuple(q), (fx, fy, fz))
    assert np.allclose(h, matrix_from_quaternion(q).T @ [fx, fy, fz], atol=1e-9)
    J = _numeric_jacobian(lambda v: accelerometer_model(tuple(v), (fx, fy, fz))[0], q)
    assert np.allclose(J, np.array(H), atol=1e-6)


def test_accelerometer_model_at_hover_is_the_printed_eq16() -> None:
    q0, q1, q2, q3 = _q(0.1, -0.2, 0.7)
    g = 9.81
    h, _ = accelerometer_model((q0, q1, q2, q3), (0.0, 0.0, g))
    printed = g * np.array([2 * (q1 * q3 - q2 * q0), 2 * (q2 * q3 + q1 * q0), q0**2 - q1**2 - q2**2 + q3**2])
    assert np.allclose(h, printed)


@given(tilts, tilts, angles)
def test_yaw_model_is_cos_sin_of_the_zyx_yaw_in_every_quadrant(r: float, p: float, y: float) -> None:
    q = np.array(_q(r, p, y))
    h, H = yaw_model(tuple(q))
    yaw = euler_from_quaternion(q)[2]
    assert np.allclose(h, [math.cos(yaw), math.sin(yaw)], atol=1e-9)
    J = _numeric_jacobian(lambda v: yaw_model(tuple(v))[0], q)
    assert np.allclose(J, np.array(H), atol=1e-6)


def test_yaw_model_agrees_with_printed_eq19_where_it_is_defined() -> None:
    for yaw in (-1.2, -0.3, 0.0, 0.4, 1.3):  # |yaw| < 90 deg: the printed form holds
        q0, q1, q2, q3 = _q(0.05, -0.03, yaw)
        gamma = 2 * (q0 * q3 + q1 * q2) / (q0**2 + q1**2 - q2**2 - q3**2)
        printed = np.array([1.0, gamma]) / math.sqrt(gamma**2 + 1.0)
        assert np.allclose(yaw_model((q0, q1, q2, q3))[0], printed)


@given(tilts, tilts, angles, st.floats(0.3, 20.0))
def test_rangefinder_model_is_the_ray_ground_distance(r: float, p: float, y: float, pz: float) -> None:
    q = np.array(_q(r, p, y))
    s, H = rangefinder_model(tuple(q), pz)
    expected = ray_ground_distance(matrix_from_quaternion(q)[None], np.array([[0.0, 0.0, pz]]))[0]
    assert s == pytest.approx(expected, rel=1e-9)
    x = np.append(q, pz)
    J = _numeric_jacobian(lambda v: [rangefinder_model(tuple(v[:4]), v[4])[0]], x)
    assert np.allclose(J[0], np.array(H), atol=1e-5)


# ---- filter invariants ---------------------------------------------------------------------------


def test_predict_covariance_is_F_P_Ft_plus_Q() -> None:
    ekf = AttitudeAltitudeEkf()
    state = ekf.initial_state(_q(0.1, 0.2, 2.0), 3.0, 0.0)
    w = np.array([0.3, -0.2, 0.5])
    out = ekf.predict(state, w, 0.01)
    F = state_transition(w, 0.01)
    s = ekf.settings
    qk = 0.25 * (0.01**2 * s.gyro_noise_rad_s**2 + 0.01 * s.attitude_random_walk_rad_sqrt_s**2)
    qn = out.q_world_body
    Q = np.zeros((5, 5))
    Q[:4, :4] = qk * (np.eye(4) - np.outer(qn, qn))
    Q[4, 4] = 0.01 * s.altitude_random_walk_m_sqrt_s**2
    assert np.allclose(out.covariance, F @ state.covariance @ F.T + Q, atol=1e-15)
    assert out.stamp_s == pytest.approx(0.01)


operations = st.lists(
    st.one_of(
        st.tuples(st.just("gyro"), rates, rates, rates, st.floats(0.0, 0.05)),
        st.tuples(st.just("accel"), st.floats(-3, 3), st.floats(-3, 3), st.floats(6, 13), st.just(0.0)),
        st.tuples(st.just("yaw"), st.floats(-20, 20), st.just(0.0), st.just(0.0), st.just(0.0)),
        st.tuples(st.just("range"), st.floats(0.5, 10.0), st.just(0.0), st.just(0.0), st.just(0.0)),
    ),
    min_size=1,
    max_size=60,
)


@settings(max_examples=60, deadline=None)
@given(tilts, tilts, angles, operations)
def test_quaternion_stays_unit_and_in_the_positive_half_space(
    r: float, p: float, y: float, ops: list[tuple[str, float, float, float, float]]
) -> None:
    ekf = AttitudeAltitudeEkf()
    state = ekf.initial_state(_q(r, p, y), 3.0, 0.0)
    for kind, a, b, c, d in ops:
        if kind == "gyro":
            state = ekf.predict(state, [a, b, c], d)
        elif kind == "accel":
            state = ekf.update_accelerometer(state, [a, b, c]).state
        elif kind == "yaw":
            state = ekf.update_yaw(state, a).state
        else:
            state = ekf.update_range(state, a).state
        q = state.q_world_body
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
        assert q[0] >= 0.0
        P = state.covariance
        assert np.allclose(P, P.T, atol=1e-9)
        assert np.all(np.linalg.eigvalsh(0.5 * (P + P.T)) > -1e-12)


@settings(max_examples=80, deadline=None)
@given(st.floats(-0.2, 0.2), st.floats(-0.02, 0.02), st.integers(-3, 3))
def test_yaw_update_is_continuous_across_180_deg(offset: float, delta: float, turns: int) -> None:
    """A state near +-180 deg and a measurement just across the cut: the correction is the small way round,
    whatever multiple of 2 pi the (unwrapped) measurement carries."""
    ekf = AttitudeAltitudeEkf()
    yaw_state = math.pi + offset
    state = ekf.initial_state(_q(0.02, -0.01, yaw_state), 3.0, 0.0)
    measured = yaw_state + delta + 2.0 * math.pi * turns
    result = ekf.update_yaw(state, measured)
    assert result.accepted
    yaw_after = euler_from_quaternion(result.state.q_world_body)[2]
    correction = float(wrap_angle_rad(yaw_after - yaw_state))
    assert abs(correction) <= abs(delta) + 1e-9
    assert correction * delta >= -1e-12  # towards the measurement


def test_full_turns_with_yaw_updates_never_jump() -> None:
    """Three full turns at 90 deg/s with a biased gyro and yaw updates at 20 Hz: the estimate follows the
    truth within a degree and consecutive estimates never jump."""
    ekf = AttitudeAltitudeEkf()
    rate = math.radians(90.0)
    dt = 0.0025
    state = ekf.initial_state(_q(0.0, 0.0, 0.0), 2.0, 0.0)
    prev = 0.0
    worst = 0.0
    for k in range(1, int(12.0 / dt) + 1):
        state = ekf.predict(state, [0.0, 0.0, rate + 0.01], dt)
        true_yaw = rate * k * dt
        if k % 20 == 0:
            state = ekf.update_yaw(state, true_yaw).state
        yaw = euler_from_quaternion(state.q_world_body)[2]
        assert abs(float(wrap_angle_rad(yaw - prev))) < 0.05
        worst = max(worst, abs(float(wrap_angle_rad(yaw - true_yaw))))
        prev = yaw
    assert worst < math.radians(1.0)


def test_an_outlier_range_is_gated_and_leaves_the_state_alone() -> None:
    ekf = AttitudeAltitudeEkf()
    state = ekf.initial_state(_q(0.0, 0.0, 0.0), 3.0, 0.0)
    for _ in range(20):
        state = ekf.update_range(state, 3.0).state
    result = ekf.update_range(state, 8.0)
    assert not result.accepted
    assert result.nis > 100.0
    assert result.state is state
    assert ekf.update_range(state, 3.01).accepted


def test_settings_and_inputs_are_validated() -> None:
    with pytest.raises(InputError):
        EkfSettings(range_noise_m=0.0)
    with pytest.raises(InputError):
        EkfSettings(gate_probability=1.0)
    ekf = AttitudeAltitudeEkf()
    state = ekf.initial_state(_q(0.0, 0.0, 0.0), 3.0, 0.0)
    with pytest.raises(InputError):
        ekf.predict(state, [0.0, 0.0], 0.01)
    with pytest.raises(InputError):
        ekf.predict(state, [0.0, 0.0, 0.0], -0.01)
    with pytest.raises(InputError):
        ekf.update_range(state, float("nan"))
    with pytest.raises(InputError):
        ekf.update_accelerometer(state, [0.0, float("inf"), 9.8])
    with pytest.raises(InputError):
        ekf.update_yaw(state, float("nan"))


# ---- flight (b) of the simulator -----------------------------------------------------------------


def _run_flight_b(visual_yaw: bool, duration_s: float = 25.0) -> tuple[np.ndarray, float]:
    """Paper C's EKF over flight (b): attitude errors (deg) and the altitude RMSE (m)."""
    run = run_over_flight_b(AttitudeAltitudeEkf(), seed=0, duration_s=duration_s, visual_yaw=visual_yaw)
    return run.errors_deg, float(np.sqrt(np.mean(np.square(run.altitude_errors_m))))


def test_tracks_flight_b_attitude_and_altitude() -> None:
    err_deg, alt_rmse_m = _run_flight_b(visual_yaw=True)
    rmse = np.sqrt(np.mean(err_deg**2, axis=0))
    assert np.all(rmse < 0.5), rmse
    assert alt_rmse_m < 0.02
    # without yaw updates the gyro bias makes the yaw drift well beyond the coupled error
    err_free, _ = _run_flight_b(visual_yaw=False)
    assert np.abs(err_free[-1, 2]) > 3.0 * rmse[2]
