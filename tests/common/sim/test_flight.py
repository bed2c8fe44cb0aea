"""Flights: the paper A hover and the paper C turns, sampled into frames, IMU and rangefinder series."""

from __future__ import annotations

import numpy as np
import pytest

from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, euler_from_quaternion, matrix_from_quaternion
from common.sim.flight import Flight, hover_flight, turns_flight
from common.sim.ground import GroundTexture, homography_between_views, render_ground_view
from common.sim.sensors import ImageDegradation


@pytest.fixture(scope="module")
def hover(texture: GroundTexture) -> Flight:
    return hover_flight(seed=0, texture=texture)


@pytest.fixture(scope="module")
def turns(texture: GroundTexture) -> Flight:
    return turns_flight(seed=0, texture=texture)


def test_hover_has_the_paper_a_shape(hover: Flight) -> None:
    assert hover.n_frames == 2041
    assert hover.frame_stamps_s[-1] == pytest.approx(102.0)
    assert np.allclose(np.diff(hover.frame_stamps_s), 0.05)
    assert hover.camera.shape == (480, 752)
    assert np.array_equal(hover.R_body_camera, R_BODY_CAMERA_DOWN)
    assert hover.imu.n_samples == 40801 and np.allclose(np.diff(hover.imu.stamps_s), 1 / 400)
    assert hover.range.n_samples == 5101 and np.allclose(np.diff(hover.range.stamps_s), 1 / 50)
    z = hover.p_world_body_m[:, 2]
    assert z.min() > 1.4 and z.max() < 1.6
    horizontal = hover.p_world_body_m[:, :2] - hover.p_world_body_m[0, :2]
    assert 0.1 < np.abs(horizontal).max() < 0.6  # slow drift of tens of cm
    tilt_deg = np.degrees(np.abs(hover.euler_rad[:, :2]))
    assert 1.5 < tilt_deg.max() < 4.0  # a few degrees


def test_hover_yaw_rates_reach_45_deg_s_both_ways(hover: Flight) -> None:
    t = np.arange(0.0, 102.0, 0.001)
    yaw_rate_deg_s = np.degrees(np.gradient(hover.trajectory.sample(t).yaw_rad, t))
    assert np.max(np.abs(yaw_rate_deg_s)) == pytest.approx(45.0, abs=0.05)
    assert yaw_rate_deg_s.max() > 30.0 and yaw_rate_deg_s.min() < -30.0
    # Several swings both ways: count the yaw-rate peaks above 15 deg/s in each direction.
    fast = np.abs(yaw_rate_deg_s) > 15.0
    starts = np.flatnonzero(np.diff(fast.astype(int)) == 1)
    signs = np.sign(yaw_rate_deg_s[starts + 1])
    assert (signs > 0).sum() >= 3 and (signs < 0).sum() >= 3
    yaw_deg = np.degrees(hover.yaw_rad)
    assert 20.0 < yaw_deg.max() - yaw_deg.min() < 120.0  # net wander over tens of degrees
    # yaw_rad is the ZYX yaw of q_world_body, unwrapped
    wrapped = euler_from_quaternion(hover.q_world_body)[:, 2]
    assert np.allclose(np.angle(np.exp(1j * (wrapped - hover.yaw_rad))), 0.0, atol=1e-9)


def test_frames_are_deterministic_and_rendered_from_the_true_pose(
    hover: Flight, texture: GroundTexture
) -> None:
    other = hover_flight(seed=0, n_frames=50, texture=texture)
    for i in (0, 17, 49):
        assert hover.frame(i).tobytes() == other.frame(i).tobytes()
    R_world_camera = matrix_from_quaternion(hover.q_world_body[17]) @ R_BODY_CAMERA_DOWN
    clean = render_ground_view(texture, hover.camera, R_world_camera, hover.p_world_body_m[17])
    assert clean.tobytes() == hover.clean_frame(17).tobytes()
    noisy = hover.frame(17).astype(np.float64)
    residual = noisy - clean
    assert 1.0 < residual.std() < 5.0  # mild sensor noise, not a different picture
    assert hover.frame(18).tobytes() != hover.frame(17).tobytes()
    assert len(list(hover.frames(5, 8))) == 3


def test_prefix_flight_has_identical_truth_and_sensors(hover: Flight, texture: GroundTexture) -> None:
    short = hover_flight(seed=0, n_frames=100, texture=texture)
    assert np.array_equal(short.q_world_body, hover.q_world_body[:100])
    m = short.imu.n_samples
    assert np.array_equal(short.imu.gyro_rad_s, hover.imu.gyro_rad_s[:m])
    assert np.array_equal(short.imu.accel_m_s2, hover.imu.accel_m_s2[:m])
    k = short.range.n_samples
    assert np.array_equal(short.range.range_m, hover.range.range_m[:k])


def test_different_seeds_give_different_flights(texture: GroundTexture) -> None:
    a = hover_flight(seed=1, n_frames=20, texture=texture)
    b = hover_flight(seed=2, n_frames=20, texture=texture)
    assert not np.allclose(a.yaw_rad, b.yaw_rad)
    assert not np.allclose(a.imu.gyro_rad_s, b.imu.gyro_rad_s)


def test_clean_degradation_gives_exact_renders(texture: GroundTexture) -> None:
    flight = hover_flight(seed=0, n_frames=10, texture=texture, degradation=ImageDegradation.clean())
    assert flight.frame(3).tobytes() == flight.clean_frame(3).tobytes()


def test_consecutive_hover_frames_are_related_by_the_true_homography(hover: Flight) -> None:
    import cv2

    i = 300
    H = homography_between_views(hover.camera, *hover.camera_pose(i), *hover.camera_pose(i + 1))
    a, b = hover.clean_frame(i), hover.clean_frame(i + 1)
    size = (hover.camera.width, hover.camera.height)
    warped = cv2.warpPerspective(a, H, size)
    valid = cv2.warpPerspective(np.full_like(a, 255), H, size) == 255
    assert np.abs(warped.astype(float) - b)[valid].mean() < 4.0


def test_frame_index_is_validated(hover: Flight) -> None:
    with pytest.raises(InputError):
        hover.frame(hover.n_frames)
    with pytest.raises(InputError):
        hover.frame(-1)
    with pytest.raises(InputError):
        hover_flight(n_frames=1)
