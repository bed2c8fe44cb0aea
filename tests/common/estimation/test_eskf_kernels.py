"""The compiled bias filter (:mod:`common.estimation.eskf_kernels`) equals the plain NumPy reference
(``eskf_reference.py``) on random states and inputs: predict (with and without the accelerometer), the
accelerometer, position, yaw and range updates, and their gating."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from common.estimation.eskf import BiasAwareEkf
from common.estimation.eskf_state import N_ERROR, BiasEkfState
from common.geometry import euler_from_quaternion, matrix_from_quaternion, quaternion_from_euler
from tests.common.estimation.eskf_reference import ReferenceEskf, ReferenceState

seeds = st.integers(0, 2**31 - 1)


def _pair(seed: int) -> tuple[BiasEkfState, ReferenceState]:
    """The same random state for both implementations (random attitude, biases, velocity, SPD covariance)."""
    rng = np.random.default_rng(seed)
    q = quaternion_from_euler(*rng.uniform([-0.5, -0.5, -math.pi], [0.5, 0.5, math.pi]))
    bg, ba = rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3)
    p, v, vz = rng.normal(0, 3, 2), rng.normal(0, 1, 2), float(rng.normal(0, 0.5))
    A = rng.normal(0, 0.05, (N_ERROR, N_ERROR))
    P = A @ A.T + np.diag(rng.uniform(1e-6, 1e-3, N_ERROR))
    pz = float(rng.uniform(0.5, 3.0))
    fast = BiasEkfState.from_parts(q, pz, bg, ba, P, 1.0, p, v, vz)
    ref = ReferenceState(q.copy(), pz, bg.copy(), ba.copy(), P.copy(), 1.0, p.copy(), v.copy(), vz)
    return fast, ref


def _assert_same(fast: BiasEkfState, ref: ReferenceState) -> None:
    assert np.allclose(fast.q_world_body, ref.q_world_body, rtol=0, atol=1e-12)
    assert math.isclose(fast.pz_m, ref.pz_m, rel_tol=0, abs_tol=1e-12)
    for a, b in (
        (fast.gyro_bias_rad_s, ref.gyro_bias_rad_s),
        (fast.accel_bias_m_s2, ref.accel_bias_m_s2),
        (fast.p_xy_m, ref.p_xy_m),
        (fast.v_xy_m_s, ref.v_xy_m_s),
    ):
        assert np.allclose(a, b, rtol=0, atol=1e-12)
    assert math.isclose(fast.vz_m_s, ref.vz_m_s, rel_tol=0, abs_tol=1e-12)
    assert np.allclose(fast.covariance, ref.covariance, rtol=1e-10, atol=1e-15)
    assert np.array_equal(fast.covariance, fast.covariance.T)  # the compiled path keeps P symmetric
    assert fast.stamp_s == ref.stamp_s


@settings(max_examples=60, deadline=None)
@given(seeds, st.floats(0.0, 0.02), st.booleans())
def test_predict_equals_the_reference(seed: int, dt_s: float, with_accel: bool) -> None:
    fast, ref = _pair(seed)
    rng = np.random.default_rng(seed + 1)
    gyro = rng.normal(0, 1.0, 3)
    accel = rng.normal(0, 3.0, 3) + np.array([0.0, 0.0, 9.8])
    a = accel if with_accel else None
    _assert_same(BiasAwareEkf().predict(fast, gyro, dt_s, a), ReferenceEskf().predict(ref, gyro, dt_s, a))


@settings(max_examples=60, deadline=None)
@given(seeds, st.floats(0.0, 2.0), st.floats(0.05, 1.5))
def test_accelerometer_update_equals_the_reference(seed: int, motion: float, noise_scale: float) -> None:
    fast, ref = _pair(seed)
    rng = np.random.default_rng(seed + 2)
    m = (float(motion), float(-0.5 * motion), 0.0)
    # a reading near the model (accepted) or far from it (gated / norm-skipped), alike for both
    f_body = matrix_from_quaternion(fast.q_world_body).T @ (np.array(m) + np.array([0.0, 0.0, 9.80665]))
    accel = f_body + fast.accel_bias_m_s2 + rng.normal(0, noise_scale, 3)
    rf = BiasAwareEkf().update_accelerometer(fast, accel, m)
    rr = ReferenceEskf().update_accelerometer(ref, accel, m)
    assert rf.accepted == rr.accepted
    if rf.accepted:
        assert math.isclose(rf.nis, rr.nis, rel_tol=1e-9)
    _assert_same(rf.state, rr.state)


@settings(max_examples=60, deadline=None)
@given(seeds, st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.5, 0.5), st.floats(-0.3, 0.3))
def test_position_yaw_and_range_updates_equal_the_reference(
    seed: int, dx: float, dy: float, dyaw: float, drange: float
) -> None:
    fast, ref = _pair(seed)
    fe, re = BiasAwareEkf(), ReferenceEskf()
    p = fast.p_xy_m + np.array([dx, dy])
    rf, rr = fe.update_position(fast, p, 0.02), re.update_position(ref, p, 0.02)
    assert rf.accepted == rr.accepted
    _assert_same(rf.state, rr.state)
    yaw = float(euler_from_quaternion(fast.q_world_body)[2]) + dyaw
    rf, rr = fe.update_yaw(rf.state, yaw, 0.05), re.update_yaw(rr.state, yaw, 0.05)
    assert rf.accepted == rr.accepted
    _assert_same(rf.state, rr.state)
    r = fast.pz_m + drange + 1.0
    rf, rr = fe.update_range(rf.state, r), re.update_range(rr.state, r)
    assert rf.accepted == rr.accepted
    _assert_same(rf.state, rr.state)
