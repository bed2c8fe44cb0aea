"""The rig in the yaw: the gyro prior's axis from the camera's mount and the IMU's axes, the IMU's clock."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    R_BODY_CAMERA_FORWARD,
    matrix_from_euler,
    matrix_from_quaternion,
)
from common.sim.field import mounted_camera
from common.sim.ground import GroundTexture, camera_pose_from_body, render_ground_view
from common.yaw import Provenance, YawSettings, YawTracker, gyro_delta_yaw_rad, make_patch_grid
from common.yaw.mount import image_turn_axis_imu, imu_stamp_s, yaw_per_image_turn

unit = st.floats(-1.0, 1.0, allow_nan=False)
quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: math.hypot(*q) > 0.1)
rates = st.tuples(*(st.floats(-5.0, 5.0, allow_nan=False),) * 3)


def _rotation(q: tuple[float, float, float, float]) -> np.ndarray:
    return matrix_from_quaternion(np.asarray(q) / math.hypot(*q))


@settings(max_examples=200, deadline=None)
@given(
    azimuth_deg=st.floats(-180.0, 180.0),
    tilt_deg=st.floats(0.0, 59.0),
    turn_deg=st.floats(-180.0, 180.0),
    q_imu=quaternions,
    omega_body=rates,
)
def test_gyro_about_the_axis_is_the_yaw_rate_times_the_cosine_of_the_tilt(
    azimuth_deg: float,
    tilt_deg: float,
    turn_deg: float,
    q_imu: tuple[float, float, float, float],
    omega_body: tuple[float, float, float],
) -> None:
    """Whatever the mount (looking down: tilted up to 59 deg towards any azimuth, turned about its axis) and
    the IMU's axes: the IMU's reading with the weights is the body's yaw rate times ``a_z``, the part of
    minus the optical axis along the body's +z (how a yaw turns the image under any mount), whatever the
    roll and pitch rates. (Down-looking mounts are drawn, not filtered from random rotations: three in four
    of those were refused, and the filtering failed Hypothesis' health check on some seeds.)"""
    towards = matrix_from_euler(0.0, 0.0, math.radians(azimuth_deg))  # the tilt's direction, about body z
    R_body_camera = towards @ mounted_camera(tilt_deg, turn_deg)
    R_body_imu = _rotation(q_imu)
    up = -R_body_camera[2, 2]
    assert up == pytest.approx(math.cos(math.radians(tilt_deg)))
    omega = np.asarray(omega_body)
    gyro_imu = R_body_imu.T @ omega
    axis = image_turn_axis_imu(R_body_camera, R_body_imu)
    assert np.linalg.norm(axis) == pytest.approx(up)
    assert float(gyro_imu @ axis) == pytest.approx(up * omega[2], abs=1e-9)


def test_a_tilted_camera_s_gyro_prior_does_not_turn_with_the_roll_regression() -> None:
    """The bug: the prior integrated the gyro about minus the optical axis, so the field suite's mounted rig
    (tilted 10 deg, turned 90 deg) turned its bridged pairs by tan(10 deg) of the roll in each."""
    tilted = mounted_camera(10.0, 90.0)
    for R_body_imu in (np.eye(3), matrix_from_euler(math.pi, 0.0, math.pi / 2.0)):
        axis = image_turn_axis_imu(tilted, R_body_imu)
        roll, pitch, yaw = np.eye(3)
        assert float((R_body_imu.T @ roll) @ axis) == pytest.approx(0.0, abs=1e-12)
        assert float((R_body_imu.T @ pitch) @ axis) == pytest.approx(0.0, abs=1e-12)
        assert float((R_body_imu.T @ yaw) @ axis) == pytest.approx(math.cos(math.radians(10.0)))
    with pytest.raises(InputError, match="looking down"):
        image_turn_axis_imu(mounted_camera(90.0, 0.0))


def test_down_camera_on_a_body_aligned_imu_is_body_z() -> None:
    assert np.allclose(image_turn_axis_imu(R_BODY_CAMERA_DOWN), [0.0, 0.0, 1.0])
    # a camera turned about its own axis turns the image the same way: the axis does not move
    assert np.allclose(image_turn_axis_imu(mounted_camera(0.0, 90.0)), [0.0, 0.0, 1.0])
    # an IMU upside down: the yaw is about its -z
    upside_down = matrix_from_euler(math.pi, 0.0, 0.0)
    assert np.allclose(image_turn_axis_imu(R_BODY_CAMERA_DOWN, upside_down), [0.0, 0.0, -1.0])
    # a camera tilted 10 deg backward (about body y): a yaw turns its image by cos(10 deg) of the angle,
    # and the pitch rate does not turn it (the optical axis leans; the weights do not)
    tilted = image_turn_axis_imu(mounted_camera(10.0, 0.0))
    assert np.allclose(tilted, [0.0, 0.0, math.cos(math.radians(10.0))])


def test_the_gyro_prior_of_a_rotated_imu_is_the_aligned_ones() -> None:
    """The same body rotation read by an IMU mounted upside down and turned: the same integrated yaw."""
    stamps = np.arange(0.0, 0.2, 0.0025)
    omega_body = np.column_stack([0.3 * np.sin(9 * stamps), 0.2 * np.ones_like(stamps), 1.0 + stamps])
    R_body_imu = matrix_from_euler(math.pi, 0.0, math.pi / 2.0)
    aligned = gyro_delta_yaw_rad(stamps, omega_body, 0.01, 0.16)
    axis = image_turn_axis_imu(R_BODY_CAMERA_DOWN, R_body_imu)
    rotated = gyro_delta_yaw_rad(stamps, omega_body @ R_body_imu, 0.01, 0.16, axis)
    assert aligned is not None and rotated == pytest.approx(aligned, abs=1e-12)


def test_imu_stamp_is_the_camera_stamp_plus_the_offset() -> None:
    assert imu_stamp_s(1.0, 0.012) == pytest.approx(1.012)
    with pytest.raises(InputError):
        imu_stamp_s(1.0, math.nan)


def test_a_reflection_is_not_a_mount() -> None:
    with pytest.raises(InputError, match="R_body_imu"):
        image_turn_axis_imu(R_BODY_CAMERA_DOWN, np.diag([1.0, 1.0, -1.0]))


@settings(max_examples=100, deadline=None)
@given(tilt_deg=st.floats(0.0, 59.0), turn_deg=st.floats(-180.0, 180.0))
def test_the_yaw_per_image_turn_is_one_over_the_cosine_of_the_tilt(tilt_deg: float, turn_deg: float) -> None:
    """A yaw rate w about body +z turns the image by w cos(tilt) (its part about the optical axis); the
    turn of the camera about its own axis does not matter."""
    R = mounted_camera(tilt_deg, turn_deg)
    k = yaw_per_image_turn(R)
    assert k == pytest.approx(1.0 / math.cos(math.radians(tilt_deg)))
    omega_body = np.array([0.0, 0.0, 0.7])
    turn_rate = float((R.T @ omega_body)[2] * -1.0)  # about minus the optical axis
    assert k * turn_rate == pytest.approx(0.7)


def test_a_camera_that_does_not_look_down_has_no_yaw() -> None:
    assert yaw_per_image_turn(R_BODY_CAMERA_DOWN) == 1.0
    with pytest.raises(InputError, match="looking down"):
        yaw_per_image_turn(R_BODY_CAMERA_FORWARD)


CAMERA = CameraModel.from_hfov(320, 240, 90.0)
TILTED = mounted_camera(20.0, 90.0)


def _view(texture: GroundTexture, yaw_deg: float, x_m: float = 0.02) -> np.ndarray:
    R_world_body = matrix_from_euler(0.0, 0.0, math.radians(yaw_deg))
    R, p = camera_pose_from_body(R_world_body, np.array([x_m, -0.01, 1.2]), TILTED)
    return render_ground_view(texture, CAMERA, R, p)


def _published_deg(
    texture: GroundTexture, mount: np.ndarray, camera: CameraModel | None, b: np.ndarray
) -> float:
    settings_ = YawSettings(camera=camera)
    tracker = YawTracker(settings_, make_patch_grid((CAMERA.height, CAMERA.width), settings_), mount)
    _, estimate = tracker.track(tracker.initial_state(_view(texture, 30.0), stamp_s=0.0), b, 0.1)
    assert estimate.provenance is Provenance.MEASURED
    return math.degrees(estimate.delta_yaw_rad)


def test_tracker_of_a_tilted_camera_publishes_the_vehicles_yaw(texture: GroundTexture) -> None:
    """A camera tilted 20 deg off the down mount and turned 90 deg about its axis: a 4 deg yaw turns the image
    by 4 cos(20) = 3.76 deg. Told the mount, the tracker publishes 4 deg (in the nadir view with intrinsics,
    scaled without); assuming the down mount, 3.76."""
    turned = _view(texture, 34.0)
    assert _published_deg(texture, TILTED, CAMERA, turned) == pytest.approx(4.0, abs=0.03)
    assert _published_deg(texture, TILTED, None, turned) == pytest.approx(4.0, abs=0.05)
    down = _published_deg(texture, R_BODY_CAMERA_DOWN, None, turned)
    assert down == pytest.approx(4.0 * math.cos(math.radians(20.0)), abs=0.05)


def test_a_tilted_camera_moving_over_the_floor_is_no_yaw_in_the_nadir_view(texture: GroundTexture) -> None:
    """Moved 6 cm sideways (no yaw): the tilted view's flow has a curl that a fit in the raw image takes
    for a turn; in the nadir view it is a translation, no turn."""
    moved = _view(texture, 30.0, x_m=0.08)
    raw = _published_deg(texture, TILTED, None, moved)
    nadir = _published_deg(texture, TILTED, CAMERA, moved)
    assert abs(nadir) < 0.03 and abs(raw) > 3.0 * abs(nadir), (raw, nadir)
