"""Trajectories: analytic derivatives vs finite differences, coordinated tilt, the two paper flights."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.geometry import (
    matrix_from_quaternion,
    quaternion_conjugate,
    quaternion_multiply,
    rotation_vector_from_quaternion,
)
from common.sim.trajectory import (
    GRAVITY_M_S2,
    AttitudeMode,
    ScalarFunction,
    SineSum,
    SmoothStep,
    TanhSteps,
    Trajectory,
    hover_trajectory,
    turns_trajectory,
)

HOVER = hover_trajectory(seed=0)
HOVER_COORDINATED = hover_trajectory(seed=4, mode=AttitudeMode.COORDINATED)
TURNS = turns_trajectory(seed=0)
TRAJECTORIES = {"hover": HOVER, "hover_coordinated": HOVER_COORDINATED, "turns": TURNS}


def _finite_difference_rate(traj: Trajectory, t: float, h: float = 1e-4) -> np.ndarray:
    """Body rate from quaternion differences: log(q(t-h)^-1 q(t+h)) / 2h."""
    q = traj.sample([t - h, t + h]).q_world_body
    dq = quaternion_multiply(quaternion_conjugate(q[0]), q[1])
    return rotation_vector_from_quaternion(dq) / (2.0 * h)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(sorted(TRAJECTORIES)), st.floats(0.01, 1.0))
def test_gyro_truth_matches_quaternion_differences(name: str, fraction: float) -> None:
    traj = TRAJECTORIES[name]
    t = fraction * traj.duration_s
    omega = traj.sample(t).omega_body_rad_s[0]
    assert np.allclose(omega, _finite_difference_rate(traj, t), atol=2e-6)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(sorted(TRAJECTORIES)), st.floats(0.01, 1.0))
def test_velocity_acceleration_jerk_match_finite_differences(name: str, fraction: float) -> None:
    traj = TRAJECTORIES[name]
    t = fraction * traj.duration_s
    h = 1e-4
    p, v, a, j = traj.path.derivatives(np.array([t - h, t, t + h]))
    assert np.allclose((p[2] - p[0]) / (2 * h), v[1], atol=1e-7)
    assert np.allclose((v[2] - v[0]) / (2 * h), a[1], atol=1e-6)
    assert np.allclose((a[2] - a[0]) / (2 * h), j[1], atol=1e-5)
    sample = traj.sample([t - h, t, t + h])
    assert np.allclose(sample.p_world_body_m, p)
    assert np.allclose(sample.v_world_m_s, v)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(["hover_coordinated", "turns"]), st.floats(0.0, 1.0))
def test_coordinated_thrust_axis_is_along_the_needed_force(name: str, fraction: float) -> None:
    traj = TRAJECTORIES[name]
    s = traj.sample(fraction * traj.duration_s)
    force = s.a_world_m_s2[0] + [0.0, 0.0, GRAVITY_M_S2]
    body_z = s.R_world_body[0][:, 2]
    assert np.allclose(body_z, force / np.linalg.norm(force), atol=1e-12)
    # an ideal accelerometer on a coordinated quadrotor reads pure thrust along body z
    f_body = s.specific_force_body_m_s2[0]
    assert np.allclose(f_body[:2], 0.0, atol=1e-9)
    assert f_body[2] == pytest.approx(np.linalg.norm(force))
    assert np.allclose(matrix_from_quaternion(s.q_world_body[0]), s.R_world_body[0])


def test_accelerometer_at_hover_reads_gravity_in_the_body() -> None:
    s = HOVER.sample(np.arange(0.0, HOVER.duration_s, 0.01))
    f = s.specific_force_body_m_s2
    assert np.allclose(f.mean(axis=0), [0.0, 0.0, 9.81], atol=0.05)
    # PRESCRIBED tilt: the specific force is gravity rotated into the tilted body (+ tiny accelerations)
    gravity_body = np.einsum("nji,j->ni", s.R_world_body, [0.0, 0.0, GRAVITY_M_S2])
    assert np.max(np.abs(f - gravity_body)) < 0.02
    assert np.max(np.abs(f[:, :2])) > 0.2  # the few-degree wobble is visible to the accelerometer


def test_coordinated_hover_tilts_a_few_degrees() -> None:
    s = HOVER_COORDINATED.sample(np.arange(0.0, HOVER_COORDINATED.duration_s, 0.01))
    tilt_deg = np.degrees(np.arccos(s.R_world_body[:, 2, 2]))
    assert 1.5 < tilt_deg.max() < 4.5
    assert np.max(np.linalg.norm(s.v_world_m_s, axis=1)) < 0.3


def test_hover_is_quasi_stationary_with_fast_yaw() -> None:
    s = HOVER.sample(np.arange(0.0, HOVER.duration_s, 0.005))
    assert np.max(np.linalg.norm(s.v_world_m_s, axis=1)) < 0.15
    assert np.max(np.abs(np.degrees(s.euler_rad[:, :2]))) < 3.5
    yaw_rate = np.degrees(HOVER.yaw.derivative(s.t_s, 1))
    assert np.max(np.abs(yaw_rate)) == pytest.approx(45.0, abs=0.05)
    assert HOVER.info["altitude_m"] == 1.5
    assert np.mean(s.p_world_body_m[:, 2]) == pytest.approx(1.5, abs=0.05)


def test_turns_flight_path_altitudes_and_turns() -> None:
    t = np.arange(0.0, TURNS.duration_s + 1e-9, 0.001)
    s = TURNS.sample(t)
    steps = np.linalg.norm(np.diff(s.p_world_body_m, axis=0), axis=1)
    length = steps.sum()
    assert TURNS.info["path_length_m"] == pytest.approx(13.832, abs=5e-4)
    assert length == pytest.approx(TURNS.info["path_length_m"], abs=1e-4)
    assert length == pytest.approx(13.8, abs=0.1)
    z = s.p_world_body_m[:, 2]
    assert z[0] == pytest.approx(3.5) and z[-1] == pytest.approx(4.0)
    assert np.all(np.diff(z) >= -1e-12)
    # smooth start and stop: at rest in the hover phases
    speed = np.linalg.norm(s.v_world_m_s, axis=1)
    assert speed[t < 5.0].max() < 1e-9 and speed[t > 45.0].max() < 1e-9
    assert 0.6 < speed.max() < 1.0
    # two turns of radius 1.1 m about the origin
    radius = np.linalg.norm(s.p_world_body_m[:, :2], axis=1)
    assert np.allclose(radius, 1.1)
    heading = np.unwrap(np.arctan2(s.v_world_m_s[speed > 1e-3, 1], s.v_world_m_s[speed > 1e-3, 0]))
    assert heading[-1] - heading[0] == pytest.approx(4.0 * np.pi, abs=0.05)
    # yaw follows the path; tilt into the turn: body z leans towards the centre
    assert s.yaw_rad[-1] - s.yaw_rad[0] == pytest.approx(4.0 * np.pi, abs=1e-9)
    mid = np.argmin(np.abs(t - 25.0))
    body_z_horizontal = s.R_world_body[mid][:2, 2]
    assert np.dot(body_z_horizontal, -s.p_world_body_m[mid, :2]) > 0.0
    tilt_deg = np.degrees(np.arccos(s.R_world_body[:, 2, 2]))
    assert 2.0 < tilt_deg.max() < 6.0


def test_angular_rate_is_continuous_at_the_manoeuvre_ends() -> None:
    for t0 in (5.0, 45.0):
        s = TURNS.sample([t0 - 1e-6, t0 + 1e-6])
        assert np.allclose(s.omega_body_rad_s[0], s.omega_body_rad_s[1], atol=1e-6)


@given(st.floats(-10.0, 10.0), st.integers(0, 2))
def test_scalar_functions_derivatives_by_finite_differences(t: float, order: int) -> None:
    h = 1e-5
    functions: list[ScalarFunction] = [
        SineSum((0.3, 0.1), (1.3, 7.0), (0.2, -1.0), 2.0),
        TanhSteps((0.7, -0.4), (-1.0, 2.0), (0.4, 0.9)),
        SmoothStep(-3.0, 6.0, 2.5),
    ]
    for f in functions:
        fd = (f.derivative(np.array([t + h]), order) - f.derivative(np.array([t - h]), order)) / (2 * h)
        assert np.allclose(fd, f.derivative(np.array([t]), order + 1), atol=1e-4)


def test_trajectories_are_deterministic_per_seed() -> None:
    t = np.linspace(0.0, 100.0, 50)
    assert np.array_equal(
        hover_trajectory(seed=7).sample(t).q_world_body, hover_trajectory(seed=7).sample(t).q_world_body
    )
    assert not np.allclose(
        hover_trajectory(seed=8).sample(t).yaw_rad, hover_trajectory(seed=7).sample(t).yaw_rad
    )


def test_invalid_trajectory_inputs() -> None:
    with pytest.raises(InputError):
        HOVER.sample(np.array([np.nan]))
    with pytest.raises(InputError):
        hover_trajectory(duration_s=-1.0)
    with pytest.raises(InputError):
        turns_trajectory(radius_m=0.0)


def test_agile_trajectory_is_fast_tilted_and_hovers_at_both_ends() -> None:
    from common.sim.trajectory import agile_trajectory

    for seed in (0, 1, 2):
        traj = agile_trajectory(seed=seed)
        info = traj.info
        assert 1.3 < info["max_speed_m_s"] < 1.7
        assert 14.0 < info["max_tilt_deg"] < 26.0
        assert info["min_altitude_m"] > 1.05 and info["max_altitude_m"] < 2.95
        ends = traj.sample(np.array([0.0, 2.0, traj.duration_s - 2.0, traj.duration_s]))
        assert np.allclose(ends.v_world_m_s, 0.0, atol=1e-12)
        assert np.allclose(ends.p_world_body_m[:, 2], 2.0)


def test_enveloped_path_derivatives_match_finite_differences() -> None:
    from common.sim.trajectory import agile_trajectory

    path = agile_trajectory(seed=3).path
    t = np.linspace(3.0, 20.0, 7)
    eps = 1e-5
    derivs = path.derivatives(t)
    plus, minus = path.derivatives(t + eps), path.derivatives(t - eps)
    for order in range(3):
        numeric = (plus[order] - minus[order]) / (2.0 * eps)
        assert np.allclose(derivs[order + 1], numeric, atol=1e-5 * (1.0 + np.abs(numeric).max()))
