"""Invariants of the rotation conventions in common.geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    R_BODY_CAMERA_FORWARD,
    check_quaternion,
    check_rotation_matrix,
    euler_from_quaternion,
    matrix_from_euler,
    matrix_from_quaternion,
    normalize_quaternion,
    quaternion_conjugate,
    quaternion_from_euler,
    quaternion_from_matrix,
    quaternion_from_rotation_vector,
    quaternion_multiply,
    rotation_vector_from_quaternion,
    wrap_angle_rad,
)

finite = st.floats(-1.0, 1.0, allow_nan=False)
quaternions = st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 1e-3)
angles = st.floats(-np.pi, np.pi, allow_nan=False)
tilts = st.floats(-1.5, 1.5, allow_nan=False)


@given(quaternions)
def test_matrix_from_quaternion_is_a_rotation(q: tuple[float, ...]) -> None:
    check_rotation_matrix(matrix_from_quaternion(q))


@given(quaternions)
def test_quaternion_matrix_round_trip_up_to_sign(q: tuple[float, ...]) -> None:
    u = normalize_quaternion(q)
    back = quaternion_from_matrix(matrix_from_quaternion(u))
    assert np.allclose(back, u, atol=1e-9) or np.allclose(back, -u, atol=1e-9)
    assert back[0] >= 0.0


@given(quaternions, quaternions)
def test_product_matches_matrix_product(a: tuple[float, ...], b: tuple[float, ...]) -> None:
    qa, qb = normalize_quaternion(a), normalize_quaternion(b)
    lhs = matrix_from_quaternion(quaternion_multiply(qa, qb))
    assert np.allclose(lhs, matrix_from_quaternion(qa) @ matrix_from_quaternion(qb), atol=1e-9)


@given(quaternions)
def test_conjugate_is_inverse(q: tuple[float, ...]) -> None:
    u = normalize_quaternion(q)
    assert np.allclose(quaternion_multiply(u, quaternion_conjugate(u)), [1, 0, 0, 0], atol=1e-12)


@given(angles, tilts, angles)
def test_euler_round_trip(roll: float, pitch: float, yaw: float) -> None:
    q = quaternion_from_euler(roll, pitch, yaw)
    assert np.allclose(matrix_from_quaternion(q), matrix_from_euler(roll, pitch, yaw), atol=1e-9)
    r, p, y = euler_from_quaternion(q)
    assert np.allclose(matrix_from_euler(r, p, y), matrix_from_euler(roll, pitch, yaw), atol=1e-9)


@settings(max_examples=50)
@given(st.tuples(finite, finite, finite))
def test_rotation_vector_round_trip(v: tuple[float, float, float]) -> None:
    rotvec = np.array(v) * 3.0
    if np.linalg.norm(rotvec) >= np.pi:
        rotvec *= (np.pi - 1e-3) / np.linalg.norm(rotvec)
    assert np.allclose(
        rotation_vector_from_quaternion(quaternion_from_rotation_vector(rotvec)), rotvec, atol=1e-9
    )


def test_yaw_is_counter_clockwise_about_up() -> None:
    R = matrix_from_euler(0.0, 0.0, np.pi / 2)
    assert np.allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])  # forward (east) turns to north


def test_batched_matrices_match_single() -> None:
    rng = np.random.default_rng(0)
    e = rng.uniform(-1, 1, size=(7, 3))
    batch = matrix_from_euler(e[:, 0], e[:, 1], e[:, 2])
    for i in range(7):
        assert np.allclose(batch[i], matrix_from_euler(*e[i]))


def test_camera_mounts_are_proper_rotations() -> None:
    check_rotation_matrix(R_BODY_CAMERA_DOWN)
    check_rotation_matrix(R_BODY_CAMERA_FORWARD)
    assert np.allclose(R_BODY_CAMERA_DOWN @ [0, 0, 1], [0, 0, -1])  # optical axis points down


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_angle_range(a: float) -> None:
    w = float(wrap_angle_rad(a))
    assert -np.pi <= w < np.pi
    assert np.isclose(np.cos(w), np.cos(a), atol=1e-6) and np.isclose(np.sin(w), np.sin(a), atol=1e-6)


@pytest.mark.parametrize("bad", [[1, 0, 0], [0, 0, 0, 0], [np.nan, 0, 0, 1], 3.0])
def test_check_quaternion_rejects_bad_input(bad: object) -> None:
    with pytest.raises(InputError):
        check_quaternion(bad)  # type: ignore[arg-type]


def test_check_rotation_matrix_rejects_reflection() -> None:
    with pytest.raises(ValueError, match="reflection"):
        check_rotation_matrix(np.diag([1.0, 1.0, -1.0]))


def test_module_constants_are_read_only_regression() -> None:
    """Issue 24: the mount rotations were writable module arrays used as default arguments: one caller's
    in-place edit would have changed every later default."""
    from common.geometry import R_BODY_CAMERA_DOWN, R_BODY_CAMERA_FORWARD

    for rotation in (R_BODY_CAMERA_DOWN, R_BODY_CAMERA_FORWARD):
        assert not rotation.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            rotation[0, 0] = 2.0
