"""The bias-estimating error-state EKF: error-state Jacobians against numerical differentiation of paper C's
observation models, the predict step, gating, and bias estimation on the simulator's flight (b)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.estimation.ekf import (
    AttitudeAltitudeEkf,
)
from common.estimation.ekf_models import (
    EkfError,
    accelerometer_model,
    altitude_from_range,
    rangefinder_model,
    yaw_model,
)
from common.estimation.eskf import BiasAwareEkf, error_jacobian
from common.estimation.eskf_math import inverse_spd
from common.estimation.eskf_state import (
    BA,
    BG,
    N_ERROR,
    PXY,
    PZ,
    THETA,
    VXY,
    VZ,
    BiasEkfSettings,
    BiasEkfState,
    error_variances,
)
from common.geometry import (
    quaternion_from_euler,
    quaternion_multiply,
)
from tests.common.estimation.flight_b import run_over_flight_b

tilts = st.floats(-0.5, 0.5, allow_nan=False)
angles = st.floats(-math.pi, math.pi, allow_nan=False)


def _perturbed(q: np.ndarray, dtheta: np.ndarray) -> tuple[float, float, float, float]:
    """``q * exp(dtheta)`` (body-frame error)."""
    angle = float(np.linalg.norm(dtheta))
    axis = dtheta / angle if angle > 0 else np.zeros(3)
    dq = np.r_[math.cos(angle / 2), math.sin(angle / 2) * axis]
    p = quaternion_multiply(q, dq)
    return (float(p[0]), float(p[1]), float(p[2]), float(p[3]))


def _numeric(fn, n: int, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(n):
        d = np.zeros(n)
        d[i] = eps
        cols.append((np.asarray(fn(d)) - np.asarray(fn(-d))) / (2 * eps))
    return np.stack(cols, axis=-1)


def _state(q: np.ndarray, pz: float = 2.0) -> BiasEkfState:
    return BiasAwareEkf().initial_state(q, pz, 0.0)


@settings(max_examples=40, deadline=None)
@given(tilts, tilts, angles)
def test_error_jacobian_is_dq_dtheta(r: float, p: float, y: float) -> None:
    q = quaternion_from_euler(r, p, y)
    numeric = _numeric(lambda d: np.array(_perturbed(q, d)), 3)
    assert np.allclose(error_jacobian(tuple(q)), numeric, atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(tilts, tilts, angles, st.floats(-2.0, 2.0), st.floats(-2.0, 2.0))
def test_accelerometer_error_jacobian_is_the_cross_product_of_h(
    r: float, p: float, y: float, ax: float, ay: float
) -> None:
    """The update's closed form ``[h]x`` equals eq. 16's quaternion Jacobian times dq/dtheta and the
    numerical derivative of eq. 16 under a body-frame perturbation."""
    q = quaternion_from_euler(r, p, y)
    f = (ax, ay, 9.80665)
    h, Hq = accelerometer_model(tuple(q), f)
    hx, hy, hz = h
    closed = np.array([[0.0, -hz, hy], [hz, 0.0, -hx], [-hy, hx, 0.0]])
    assert np.allclose(np.array(Hq) @ error_jacobian(tuple(q)), closed, atol=1e-9)
    numeric = _numeric(lambda d: accelerometer_model(_perturbed(q, d), f)[0], 3)
    assert np.allclose(closed, numeric, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(tilts, tilts, angles)
def test_yaw_and_range_error_jacobians_match_numerical(r: float, p: float, y: float) -> None:
    q = quaternion_from_euler(r, p, y)
    _, Hy = yaw_model(tuple(q))
    numeric = _numeric(lambda d: yaw_model(_perturbed(q, d))[0], 3)
    assert np.allclose(np.array(Hy) @ error_jacobian(tuple(q)), numeric, atol=1e-6)
    _, Hr = rangefinder_model(tuple(q), 2.0)
    numeric = _numeric(lambda d: rangefinder_model(_perturbed(q, d), 2.0)[0], 3)
    assert np.allclose(np.array(Hr[:4]) @ error_jacobian(tuple(q)), numeric, atol=1e-6)


@settings(max_examples=30, deadline=None)
@given(tilts, tilts, angles, st.floats(0.3, 10.0))
def test_altitude_from_range_inverts_eq21(r: float, p: float, y: float, pz: float) -> None:
    q = tuple(float(v) for v in quaternion_from_euler(r, p, y))
    s, _ = rangefinder_model(q, pz)  # type: ignore[arg-type]
    assert altitude_from_range(q, s) == pytest.approx(pz, rel=1e-12)  # type: ignore[arg-type]


def test_the_initial_covariance_puts_each_settings_std_on_its_block() -> None:
    s = BiasEkfSettings(
        initial_attitude_std_rad=0.1, initial_altitude_std_m=0.2, initial_velocity_std_m_s=0.7
    )
    P = BiasAwareEkf(s).initial_state([1.0, 0.0, 0.0, 0.0], 1.0, 0.0).covariance
    diag = P.diagonal()
    assert np.array_equal(P, np.diag(diag))
    g, a = s.initial_gyro_bias_std_rad_s**2, s.initial_accel_bias_std_m_s2**2
    blocks: list[tuple[slice | int, float]] = [(THETA, 0.01), (PZ, 0.04), (BG, g), (BA, a), (PXY, 0.0)]
    for block, variance in [*blocks, (VXY, 0.49), (VZ, 0.49)]:
        assert np.allclose(diag[block], variance, rtol=1e-15, atol=0.0)
    gyro, accel = s.initial_gyro_bias_std_rad_s, s.initial_accel_bias_std_m_s2
    assert np.array_equal(diag, error_variances(0.1, 0.2, gyro, accel, 0.7))


def test_predict_propagates_the_bias_corrected_gyro_and_grows_the_covariance() -> None:
    ekf = BiasAwareEkf()
    q0 = quaternion_from_euler(0.1, -0.05, 0.3)
    state = ekf.initial_state(q0, 1.0, 0.0)
    bias = np.array([0.01, -0.02, 0.03])
    state = BiasEkfState.from_parts(state.q_world_body, 1.0, bias, np.zeros(3), state.covariance, 0.0)
    for _ in range(400):
        state = ekf.predict(state, bias, 0.0025)  # the gyro reads only its bias: no rotation
    assert np.allclose(state.q_world_body, q0, atol=1e-12)
    assert state.stamp_s == pytest.approx(1.0)
    # the attitude grows by the gyro-bias uncertainty over 1 s, and correlates with it (F_theta_bg = -I dt)
    P = state.covariance
    assert P[0, 0] > ekf.settings.initial_attitude_std_rad**2
    assert P[0, 4] < 0.0
    assert np.allclose(P, P.T, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(P) > 0.0)


def test_an_outlier_is_gated_and_bad_input_refused() -> None:
    ekf = BiasAwareEkf()
    state = ekf.initial_state([1.0, 0.0, 0.0, 0.0], 2.0, 0.0)
    assert not ekf.update_range(state, 9.0).accepted
    assert ekf.update_range(state, 2.01).accepted
    with pytest.raises(InputError):
        ekf.update_range(state, math.nan)
    with pytest.raises(InputError):
        ekf.predict(state, [0.0, 0.0, 0.0], -1.0)
    with pytest.raises(InputError):
        ekf.update_accelerometer(state, [0.0, math.inf, 9.8])
    with pytest.raises(InputError):
        BiasEkfSettings(initial_accel_bias_std_m_s2=-1.0)
    with pytest.raises(EkfError):
        inverse_spd(np.zeros((3, 3)))


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 3), st.integers(0, 1000))
def test_closed_form_inverse_matches_numpy(m: int, seed: int) -> None:
    A = np.random.default_rng(seed).normal(size=(m, m))
    S = A @ A.T + 0.1 * np.eye(m)
    assert np.allclose(inverse_spd(S), np.linalg.inv(S), rtol=1e-9, atol=1e-12)


def _run(ekf, seed: int, duration_s: float = 30.0) -> tuple[np.ndarray, object, object]:
    """The filter over flight (b): roll, pitch, yaw errors (deg) at every IMU sample, final state, IMU."""
    run = run_over_flight_b(ekf, seed=seed, duration_s=duration_s)
    return run.errors_deg, run.state, run.imu


@pytest.mark.parametrize("seed", [1])
def test_bias_states_remove_the_tilt_error_of_an_accelerometer_bias(seed: int) -> None:
    """Seed 1 has a 0.11 m/s^2 accelerometer bias: paper C's filter reads it as a 0.8 deg pitch error for
    the whole flight; once the turns make the bias observable (body-fixed bias, world-fixed tilt), the
    bias filter estimates it within 0.01 m/s^2 and its tilt error drops below 0.1 deg. The manoeuvre
    acceleration here is the truth's and nothing aids the position, so the accelerometer's noise grows by
    the acceleration once (the default share assumes a VO fit, as uncertain as it is large, and the VO
    position aiding the inertial navigation: neither is here)."""
    err5, _, _ = _run(AttitudeAltitudeEkf(), seed)
    errb, state, imu = _run(BiasAwareEkf(BiasEkfSettings(motion_accel_noise_share=1.0)), seed)
    late = slice(len(errb) // 2, None)
    rms5 = np.sqrt(np.mean(err5[late, :2] ** 2, axis=0))
    rmsb = np.sqrt(np.mean(errb[late, :2] ** 2, axis=0))
    assert np.max(rms5) > 0.5
    assert np.max(rmsb) < 0.1, rmsb
    assert np.allclose(state.accel_bias_m_s2[:2], imu.accel_bias_m_s2[-1, :2], atol=0.01)  # type: ignore[attr-defined]
    assert np.allclose(state.gyro_bias_rad_s, imu.gyro_bias_rad_s[-1], atol=math.radians(0.02))  # type: ignore[attr-defined]
    assert state.covariance.shape == (N_ERROR, N_ERROR)  # type: ignore[attr-defined]
