"""Field scenarios: deterministic, exact truth, the motion limits the issue names, exact lens rendering."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from common.camera import CameraModel, DistortionModel
from common.sim.field import (
    FIELD_LENSES,
    FIELD_SCENARIOS,
    ExposureSteps,
    FieldError,
    checkerboard_texture,
    field_flight,
    field_trajectory,
    pixel_rays,
    render_lens_view,
    scenario_camera,
    tiled_texture,
    wide_angle_camera,
)
from common.sim.ground import make_ground_texture, nadir_camera_pose, render_ground_view


def test_field_flight_is_deterministic_by_seed_and_has_imu() -> None:
    a = field_flight("field", seed=2, n_frames=12)
    b = field_flight("field", seed=2, n_frames=12)
    assert np.array_equal(a.frame(7), b.frame(7))
    assert not np.array_equal(a.frame(7), field_flight("field", seed=3, n_frames=12).frame(7))
    assert a.imu.n_samples > 20 * (a.n_frames - 1)
    assert a.camera.is_distorted and a.camera.shape == a.frame(0).shape


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_low_altitude_field_trajectory_respects_the_issues_limits(seed: int) -> None:
    trajectory = field_trajectory(
        seed, duration_s=60.0, altitude_m=(0.3, 1.3), max_drift_m_s=0.3, max_yaw_rate_deg_s=60.0
    )
    t = np.arange(0.0, 60.0, 0.001)
    s = trajectory.sample(t)
    z = s.p_world_body_m[:, 2]
    assert z.min() == pytest.approx(0.3, abs=1e-9) and z.max() == pytest.approx(1.3, abs=1e-6)
    assert np.abs(s.v_world_m_s[:, 2]).max() <= 0.4 + 1e-9
    assert np.abs(s.v_world_m_s[:, 2]).max() > 0.39  # it does climb that fast
    assert np.hypot(s.v_world_m_s[:, 0], s.v_world_m_s[:, 1]).max() <= 0.3 + 1e-9
    yaw_rate = trajectory.yaw.derivative(t, 1)
    assert math.degrees(np.abs(yaw_rate).max()) == pytest.approx(60.0, rel=1e-6)


def test_floors_are_periodic_patterns_of_the_requested_size() -> None:
    board = checkerboard_texture(seed=0, square_m=0.10, grain_dn=0.0)
    n = round(0.10 / board.texel_m)
    level = board.levels[0].astype(int)
    assert abs(level[n // 2, n // 2] - level[n // 2, n + n // 2]) > 150  # neighbouring squares differ
    assert level[n // 2, n // 2] == level[n // 2, 2 * n + n // 2]  # and repeat every two
    tiles = tiled_texture(seed=0, tile_m=0.3)
    m = round(0.3 / tiles.texel_m)
    grey = tiles.levels[0].astype(int)
    assert grey[m // 2, 0] < grey[m // 2, m // 2] - 50  # a grout line at every tile edge
    with pytest.raises(FieldError):
        checkerboard_texture(square_m=0.0)


def test_lens_renderer_matches_the_homography_renderer_for_a_pinhole() -> None:
    texture = make_ground_texture(seed=1, size_px=1024, texel_m=0.004)
    camera = CameraModel.from_hfov(320, 240, 90.0)
    R, p = nadir_camera_pose(0.1, -0.2, 1.0, 0.3)
    exact = render_ground_view(texture, camera, R, p).astype(float)
    cast = render_lens_view(texture, pixel_rays(camera), R, p)
    assert np.mean(np.abs(exact - cast)) < 1.5


def test_distorted_view_undistorts_to_the_pinhole_view() -> None:
    """Rendering through the barrel lens, then undistorting the image, gives the pinhole twin's view."""
    texture = make_ground_texture(seed=1, size_px=1024, texel_m=0.004)
    wide = wide_angle_camera()
    R, p = nadir_camera_pose(0.0, 0.0, 1.0, 0.5)
    distorted = render_lens_view(texture, pixel_rays(wide), R, p)
    pinhole = render_lens_view(texture, pixel_rays(wide.pinhole()), R, p)
    v, u = np.mgrid[0:240, 0:320]
    through_lens = wide.distort_px(np.stack([u.ravel(), v.ravel()], 1).astype(float))
    maps = through_lens.reshape(240, 320, 2).astype(np.float32)
    undistorted = cv2.remap(distorted, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR)
    centre = (slice(60, 180), slice(80, 240))

    def smooth(image: np.ndarray) -> np.ndarray:  # the barrel lens has fewer pixels per texel: compare the
        return np.asarray(cv2.GaussianBlur(image, (0, 0), 1.5))[centre]  # geometry, not the resolution

    assert np.mean(np.abs(smooth(undistorted) - smooth(pinhole))) < 1.5
    assert np.mean(np.abs(smooth(distorted) - smooth(pinhole))) > 5.0  # the lens does distort


def test_motion_blur_follows_image_motion_and_exposure_steps_are_bounded() -> None:
    still = field_flight("fast_yaw", seed=0, n_frames=40)
    blurred = field_flight("blur_exposure", seed=0, n_frames=40)
    assert all(still.subframes(i) == 1 for i in range(0, 40, 13))
    counts = [blurred.subframes(i) for i in range(40)]
    assert max(counts) > 1 and len(set(counts)) > 1  # more sub-frames where the image moves more
    steps = ExposureSteps(0.02, 1.4)
    gains = [steps.gain(t, 0, 30.0) for t in np.arange(0.0, 30.0, 0.05)]
    assert min(gains) >= 1 / 1.4 - 1e-9 and max(gains) <= 1.4 + 1e-9 and np.ptp(gains) > 0.1


def test_every_named_scenario_builds() -> None:
    for name in FIELD_SCENARIOS:
        flight = field_flight(name, n_frames=3)
        assert flight.frame(2).dtype == np.uint8
    with pytest.raises(FieldError):
        field_flight("moon")


def test_the_field_camera_keeps_each_lens_view_at_another_size() -> None:
    wide = scenario_camera(FIELD_SCENARIOS["field"], 1280, 720)
    assert wide.shape == (720, 1280) and wide.distortion.model.value == "radtan"
    narrow = scenario_camera(FIELD_SCENARIOS["checkerboard"], 640, 480)
    small = scenario_camera(FIELD_SCENARIOS["checkerboard"], 320, 240)
    assert narrow.fx == pytest.approx(2 * small.fx, rel=1e-2)  # the same 90 deg view, twice the pixels


@pytest.mark.parametrize("lens", list(FIELD_LENSES))
def test_a_named_lens_spans_its_field_of_view_at_any_size(lens: str) -> None:
    """``--field-lens``: each named lens's edge pixel (of the middle row) is half its horizontal field of
    view off-axis, at 320x240 and at 1280x960; the fisheyes are equidistant (OpenCV's fisheye model)."""
    hfov_deg = float(lens.removeprefix("pinhole").removeprefix("radtan").removeprefix("fisheye"))
    for width, height in ((320, 240), (1280, 960)):
        camera = scenario_camera(FIELD_SCENARIOS["field"], width, height, lens=lens)
        assert camera.shape == (height, width)
        ray = camera.rays(np.array([[width / 2.0 - 0.5 + width / 2.0, camera.cy]]))[0]
        assert math.degrees(math.atan2(math.hypot(ray[0], ray[1]), ray[2])) == pytest.approx(
            hfov_deg / 2, abs=0.5
        )
    assert (camera.distortion.model is DistortionModel.FISHEYE) == lens.startswith("fisheye")


def test_an_unknown_lens_is_one_field_error() -> None:
    with pytest.raises(FieldError, match="fisheye120"):
        scenario_camera(FIELD_SCENARIOS["field"], lens="tele400")


@pytest.mark.parametrize("rate_hz", [5.0, 60.0])
def test_a_field_flight_at_another_frame_rate_spans_its_time_at_that_rate(rate_hz: float) -> None:
    """``--field-fps``: frames ``1 / rate`` apart, the IMU covering the same span at its own rate, and a
    shutter no longer than the frame interval."""
    flight = field_flight("field", seed=4, n_frames=31, camera_rate_hz=rate_hz)
    assert np.allclose(np.diff(flight.frame_stamps_s), 1.0 / rate_hz)
    assert flight.imu.stamps_s[-1] >= flight.frame_stamps_s[-1] - 0.011
    assert flight.exposure.exposure_s == pytest.approx(min(0.02, 1.0 / rate_hz))
    for bad in (0.0, -20.0, math.nan, 5000.0):
        with pytest.raises(FieldError, match="camera_rate_hz"):
            field_flight("field", n_frames=3, camera_rate_hz=bad)
