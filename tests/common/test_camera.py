"""Pinhole camera: projection by hand, round trips, validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.camera import CameraModel, Distortion, DistortionModel
from common.errors import InputError


def test_default_intrinsics_are_the_documented_ones() -> None:
    cam = CameraModel.default()
    assert (cam.width, cam.height) == (752, 480)
    assert cam.fx == pytest.approx(376.0)
    assert cam.fy == pytest.approx(376.0)
    assert (cam.cx, cam.cy) == (375.5, 239.5)
    assert np.degrees(cam.hfov_rad) == pytest.approx(90.0)
    assert cam.shape == (480, 752)


def test_project_matches_a_hand_computed_point() -> None:
    cam = CameraModel(width=640, height=480, fx=500.0, fy=400.0, cx=320.0, cy=240.0)
    # (0.2, -0.1, 2.0): u = 500 * 0.1 + 320 = 370, v = 400 * (-0.05) + 240 = 220
    assert np.allclose(cam.project([0.2, -0.1, 2.0]), [370.0, 220.0])
    assert np.allclose(cam.project([[0.0, 0.0, 5.0]]), [[320.0, 240.0]])
    assert np.allclose(cam.K @ np.array([0.2, -0.1, 2.0]) / 2.0, [370.0, 220.0, 1.0])


@given(st.floats(-500.0, 1200.0), st.floats(-500.0, 900.0), st.floats(0.1, 50.0, allow_nan=False))
def test_rays_and_project_are_inverse(u: float, v: float, depth: float) -> None:
    cam = CameraModel.default()
    point = cam.rays([u, v]) * depth
    assert np.allclose(cam.project(point), [u, v], atol=1e-8)
    assert np.allclose(cam.K_inv @ cam.K, np.eye(3))


def test_bad_inputs_raise_input_error() -> None:
    cam = CameraModel.default()
    with pytest.raises(InputError, match="in front"):
        cam.project([0.0, 0.0, -1.0])
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        cam.project(np.zeros((4, 2)))
    with pytest.raises(InputError, match="finite"):
        cam.project([np.nan, 0.0, 1.0])
    with pytest.raises(InputError, match="positive"):
        CameraModel(width=10, height=10, fx=-1.0, fy=1.0, cx=5.0, cy=5.0)
    with pytest.raises(InputError):
        CameraModel.from_hfov(752, 480, 180.0)


# ---- lens distortion -------------------------------------------------------------------------------------

RADTAN_WIDE = Distortion(DistortionModel.RADTAN, (-0.28, 0.07, 0.0008, -0.0005, 0.0))
FISHEYE_WIDE = Distortion(DistortionModel.FISHEYE, (-0.013, 0.02, -0.01, 0.002))
#: pinhole-equivalent HFOV of the test cameras (a fisheye's corners must stay within 90 deg of the axis).
HFOV_OF = {DistortionModel.RADTAN: 110.0, DistortionModel.FISHEYE: 90.0}


def _points_in_view(cam: CameraModel, n: int, seed: int) -> np.ndarray:
    """Camera-frame points whose ideal projections lie inside the image."""
    rng = np.random.default_rng(seed)
    px = np.stack([rng.uniform(0, cam.width - 1, n), rng.uniform(0, cam.height - 1, n)], axis=1)
    rays = np.stack([(px[:, 0] - cam.cx) / cam.fx, (px[:, 1] - cam.cy) / cam.fy, np.ones(n)], axis=1)
    return rays * rng.uniform(0.5, 5.0, n)[:, None]


def test_radtan_projection_equals_opencv_projectPoints() -> None:
    import cv2

    cam = CameraModel.from_hfov(320, 240, 100.0, RADTAN_WIDE)
    pts = _points_in_view(cam, 200, seed=1)
    expected, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, np.array(RADTAN_WIDE.coeffs))
    np.testing.assert_allclose(cam.project(pts), expected.reshape(-1, 2), atol=1e-9)


def test_fisheye_projection_equals_opencv_fisheye_projectPoints() -> None:
    import cv2

    cam = CameraModel.from_hfov(320, 240, 90.0, FISHEYE_WIDE)  # f = 160 px: about 120 deg through the lens
    pts = _points_in_view(cam, 200, seed=2)
    expected, _ = cv2.fisheye.projectPoints(
        pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, np.array(FISHEYE_WIDE.coeffs)
    )
    np.testing.assert_allclose(cam.project(pts), expected.reshape(-1, 2), atol=1e-9)


@pytest.mark.parametrize("distortion", [RADTAN_WIDE, FISHEYE_WIDE], ids=["radtan", "fisheye"])
@given(u=st.floats(0.0, 319.0), v=st.floats(0.0, 239.0))
def test_rays_invert_project_through_the_lens(distortion: Distortion, u: float, v: float) -> None:
    cam = CameraModel.from_hfov(320, 240, HFOV_OF[distortion.model], distortion)
    ray = cam.rays([u, v])
    assert np.all(np.isfinite(ray))
    np.testing.assert_allclose(cam.project(ray), [u, v], atol=1e-7)


@pytest.mark.parametrize("distortion", [RADTAN_WIDE, FISHEYE_WIDE], ids=["radtan", "fisheye"])
def test_undistort_px_and_distort_px_are_inverse(distortion: Distortion) -> None:
    cam = CameraModel.from_hfov(320, 240, HFOV_OF[distortion.model], distortion)
    rng = np.random.default_rng(4)
    px = np.stack([rng.uniform(0, 319, 100), rng.uniform(0, 239, 100)], axis=1)
    ideal = cam.undistort_px(px)
    np.testing.assert_allclose(cam.distort_px(ideal), px, atol=1e-7)
    # barrel distortion pulls the image in: undistorted corners lie farther from the centre
    centre = np.array([cam.cx, cam.cy])
    corner = cam.corners_px()[:1]
    assert np.linalg.norm(cam.undistort_px(corner) - centre) > np.linalg.norm(corner - centre)


def test_no_distortion_is_the_pinhole() -> None:
    cam = CameraModel.from_hfov(320, 240, 90.0)
    assert not cam.is_distorted
    px = np.array([[10.0, 20.0], [300.0, 200.0]])
    np.testing.assert_array_equal(cam.undistort_px(px), px)
    assert Distortion(DistortionModel.NONE, (0.0,) * 5).is_identity


def test_a_lens_model_that_folds_back_inside_the_image_is_refused() -> None:
    with pytest.raises(InputError, match="not invertible"):
        CameraModel.from_hfov(320, 240, 120.0, Distortion(DistortionModel.RADTAN, (-0.9, 0.0, 0.0, 0.0, 0.0)))


@pytest.mark.parametrize(
    ("model", "coeffs", "match"),
    [
        (DistortionModel.RADTAN, (0.1, 0.2), "takes 5 coefficients"),
        (DistortionModel.FISHEYE, (0.1, 0.2, 0.3, 0.4, 0.5), "takes 4 coefficients"),
        (DistortionModel.RADTAN, (float("nan"), 0, 0, 0, 0), "finite"),
    ],
)
def test_bad_distortion_coefficients_are_refused(model: DistortionModel, coeffs: tuple, match: str) -> None:
    with pytest.raises(InputError, match=match):
        Distortion(model, coeffs)


def test_scaled_camera_projects_to_scaled_pixels() -> None:
    cam = CameraModel.from_hfov(752, 480, 90.0, RADTAN_WIDE)
    half = cam.scaled(0.5)
    pts = _points_in_view(cam, 50, seed=5)
    np.testing.assert_allclose((cam.project(pts) + 0.5) * 0.5 - 0.5, half.project(pts), atol=1e-9)
