"""Ground texture and rendering: determinism, exact geometry, anti-aliasing, speed-independent behaviour."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, matrix_from_euler
from common.sim.field import fisheye_camera
from common.sim.flight import hover_flight
from common.sim.ground import (
    GroundTexture,
    GroundViewError,
    ground_homography,
    ground_texture_from_image,
    homography_between_views,
    make_ground_texture,
    nadir_camera_pose,
    render_ground_view,
    render_pair,
)


def test_texture_is_deterministic_and_seed_dependent() -> None:
    a = make_ground_texture(seed=5, size_px=256)
    b = make_ground_texture(seed=5, size_px=256)
    c = make_ground_texture(seed=6, size_px=256)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(a.levels, b.levels, strict=True))
    assert a.levels[0].tobytes() != c.levels[0].tobytes()


def test_texture_has_detail_at_every_scale(texture: GroundTexture) -> None:
    # Equal variance per octave (1/f amplitude): band energy of octave k is about constant.
    level0 = texture.levels[0].astype(np.float64)
    assert 100.0 < level0.mean() < 156.0
    assert 25.0 < level0.std() < 50.0
    power = np.abs(np.fft.rfft2(level0 - level0.mean())) ** 2
    n = level0.shape[0]
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.rfftfreq(n)[None, :]
    radius = np.sqrt(fx * fx + fy * fy)
    bands = [power[(radius >= 0.5 / 2 ** (k + 1)) & (radius < 0.5 / 2**k)].sum() for k in range(9)]
    assert max(bands) / min(bands) < 3.0, bands


def test_pyramid_levels_halve_and_stay_periodic(small_texture: GroundTexture) -> None:
    sizes = [level.shape[0] for level in small_texture.levels]
    assert sizes == [512, 256, 128, 64, 32]
    # Periodic: the wrapped seam is as smooth as the interior (no jump at the tile edge).
    level = small_texture.levels[1].astype(np.float64)
    seam = np.abs(level[:, 0] - level[:, -1]).mean()
    interior = np.abs(np.diff(level, axis=1)).mean()
    assert seam < 1.5 * interior


DOT_SIGMA_M = 0.025


def _dot_texture() -> GroundTexture:
    """A black 16 m tile (wider than any view) with a Gaussian bright dot at world (0.3, -0.2)."""
    n, texel = 2048, 0.008
    origin = -0.5 * n * texel
    cols = (np.arange(n) * texel + origin)[None, :]
    rows = (np.arange(n) * texel + origin)[:, None]
    blob = 255.0 * np.exp(-((cols - 0.3) ** 2 + (rows + 0.2) ** 2) / (2.0 * DOT_SIGMA_M**2))
    return ground_texture_from_image(np.clip(np.rint(blob), 0, 255).astype(np.uint8), texel)


@pytest.fixture(scope="module")
def dot_texture() -> GroundTexture:
    return _dot_texture()


def _centroid(image: np.ndarray) -> np.ndarray:
    w = image.astype(np.float64)
    w[w < 20.0] = 0.0
    ys, xs = np.indices(w.shape)
    return np.array([(w * xs).sum() / w.sum(), (w * ys).sum() / w.sum()])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.floats(40.0, 712.0),
    st.floats(40.0, 440.0),
    st.floats(1.0, 5.0),
    st.floats(-np.pi, np.pi),
    st.floats(-0.15, 0.15),
    st.floats(-0.15, 0.15),
)
def test_bright_dot_lands_where_the_camera_projects_it(
    dot_texture: GroundTexture, u: float, v: float, altitude: float, yaw: float, roll: float, pitch: float
) -> None:
    cam = CameraModel.default()
    R_world_camera = matrix_from_euler(roll, pitch, yaw) @ R_BODY_CAMERA_DOWN
    dot_world = np.array([0.3, -0.2, 0.0])
    # place the camera at `altitude` so that the dot is seen at pixel (u, v)
    ray_world = R_world_camera @ cam.rays([u, v])
    p_world_camera = dot_world + (altitude / -ray_world[2]) * -ray_world
    assert p_world_camera[2] == pytest.approx(altitude)
    image = render_ground_view(dot_texture, cam, R_world_camera, p_world_camera)
    expected = cam.project(R_world_camera.T @ (dot_world - p_world_camera))
    assert np.allclose(expected, [u, v])
    # Independent renderer: cast each pixel's ray to the ground and evaluate the blob analytically.
    ys, xs = np.mgrid[0 : cam.height, 0 : cam.width]
    rays = cam.rays(np.column_stack([xs.ravel(), ys.ravel()])) @ R_world_camera.T
    ground = p_world_camera[:2] + rays[:, :2] * (-p_world_camera[2] / rays[:, 2:3])
    ray_cast = 255.0 * np.exp(-np.sum((ground - dot_world[:2]) ** 2, axis=1) / (2.0 * DOT_SIGMA_M**2))
    ray_cast_centroid = _centroid(ray_cast.reshape(cam.shape))
    # the perspective image of a round dot is not centred on the dot's projection: allow for that
    assert np.allclose(ray_cast_centroid, expected, atol=0.3)
    assert np.allclose(_centroid(image), ray_cast_centroid, atol=0.1)


def test_warping_one_view_by_the_true_homography_gives_the_other(texture: GroundTexture) -> None:
    cam = CameraModel.default()
    pose_a = (matrix_from_euler(0.03, -0.02, 0.4) @ R_BODY_CAMERA_DOWN, np.array([0.1, 0.2, 1.5]))
    pose_b = (matrix_from_euler(-0.02, 0.04, 0.55) @ R_BODY_CAMERA_DOWN, np.array([0.15, 0.12, 1.55]))
    image_a, image_b, H_b_a = render_pair(texture, cam, pose_a, pose_b)
    warped = cv2.warpPerspective(image_a, H_b_a, (cam.width, cam.height), flags=cv2.INTER_LINEAR)
    valid = cv2.warpPerspective(np.full_like(image_a, 255), H_b_a, (cam.width, cam.height)) == 255
    valid = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert valid.mean() > 0.6
    diff = np.abs(warped.astype(np.float64) - image_b)[valid]
    # Consistent views: residual is re-sampling blur only, far below the texture's contrast (~35 DN).
    assert diff.mean() < 4.0
    # Sanity check that the test can fail: a wrong homography (1 deg off) leaves a large residual.
    R = cv2.getRotationMatrix2D((cam.cx, cam.cy), 1.0, 1.0)
    wrong = cv2.warpPerspective(warped, np.vstack([R, [0, 0, 1]]), (cam.width, cam.height))
    assert np.abs(wrong.astype(np.float64) - image_b)[valid].mean() > 3.0 * diff.mean()


def test_nadir_views_differ_by_a_pure_rotation_about_the_image_centre() -> None:
    cam = CameraModel.default()
    pose_a = nadir_camera_pose(0.0, 0.0, 1.5, yaw_rad=0.2)
    pose_b = nadir_camera_pose(0.0, 0.0, 1.5, yaw_rad=0.2 + np.radians(7.0))
    H = homography_between_views(cam, *pose_a, *pose_b)
    # Convention others rely on: the pixel homography a -> b of nadir views is a rotation about the
    # principal point by +dyaw in (u right, v down) coordinates: dyaw = atan2(H[1, 0], H[0, 0]).
    assert np.degrees(np.arctan2(H[1, 0], H[0, 0])) == pytest.approx(7.0, abs=1e-9)
    assert np.allclose(H @ [cam.cx, cam.cy, 1.0], [cam.cx, cam.cy, 1.0])


def test_render_is_deterministic_and_fills_the_frame(texture: GroundTexture) -> None:
    cam = CameraModel.default()
    pose = nadir_camera_pose(12.3, -40.0, 2.0, 1.0)  # far outside the tile: wraps
    a = render_ground_view(texture, cam, *pose)
    b = render_ground_view(texture, cam, *pose)
    assert a.shape == (480, 752) and a.dtype == np.uint8
    assert a.tobytes() == b.tobytes()
    assert a.std() > 20.0
    assert a.min() < 80 and a.max() > 180


@pytest.mark.parametrize("altitude", [1.0, 2.0, 3.0, 5.0])
def test_mipmapping_matches_a_supersampled_reference(texture: GroundTexture, altitude: float) -> None:
    """Anti-aliasing: close to a 6x supersampled, box-filtered render; better than sampling level 0."""
    cam = CameraModel.default()
    s = 6
    big = CameraModel(cam.width * s, cam.height * s, cam.fx * s, cam.fy * s, (cam.cx + 0.5) * s - 0.5,
                        (cam.cy + 0.5) * s - 0.5)  # fmt: skip
    R, p = nadir_camera_pose(0.3, 0.2, altitude, 0.4)
    reference = cv2.resize(
        render_ground_view(texture, big, R, p, lod_bias=-30.0).astype(np.float32),
        (cam.width, cam.height),
        interpolation=cv2.INTER_AREA,
    )
    rendered = render_ground_view(texture, cam, R, p).astype(np.float32)
    aliased = render_ground_view(texture, cam, R, p, lod_bias=-30.0).astype(np.float32)
    err = float(np.sqrt(np.mean((rendered - reference) ** 2)))
    err_aliased = float(np.sqrt(np.mean((aliased - reference) ** 2)))
    assert err < 0.25 * reference.std()
    assert err <= 1.05 * err_aliased
    if altitude >= 2.5:
        assert err < 0.8 * err_aliased


def test_bad_views_raise() -> None:
    cam = CameraModel.default()
    with pytest.raises(GroundViewError, match="above the ground"):
        ground_homography(cam, *nadir_camera_pose(0.0, 0.0, -1.0))
    looking_forward = matrix_from_euler(0.0, 0.0, 0.0) @ np.array(
        [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    )
    with pytest.raises(GroundViewError, match="horizon"):
        ground_homography(cam, looking_forward, [0.0, 0.0, 1.0])
    with pytest.raises(InputError):
        ground_homography(cam, np.eye(2), [0.0, 0.0, 1.0])
    with pytest.raises(InputError):
        make_ground_texture(size_px=1000)
    with pytest.raises(InputError):
        ground_texture_from_image(np.zeros((100, 100), np.uint8), 0.01)


@given(st.integers(-3000, 3000), st.integers(-3000, 3000), st.integers(1, 300), st.integers(1, 300))
def test_periodic_crop_matches_modular_indexing(x0: int, y0: int, width: int, height: int) -> None:
    from common.sim.ground import _crop_periodic

    image = (np.arange(64)[:, None] * 7 + np.arange(128)[None, :] * 3).astype(np.uint8)
    expected = image[np.ix_(np.arange(y0, y0 + height) % 64, np.arange(x0, x0 + width) % 128)]
    assert np.array_equal(_crop_periodic(image, x0, y0, width, height), expected)


def test_the_ground_view_refuses_a_lens_it_cannot_draw_regression() -> None:
    """Regression: the homography renderer drew a distorted camera as its pinhole, so a flight given a
    fisheye (``turns_flight(camera=...)``) published pinhole frames with a fisheye's calibration. It is one
    clear error now, naming the renderer that draws any lens."""
    texture = make_ground_texture(0)
    fisheye = fisheye_camera(320, 240, 120.0)
    with pytest.raises(GroundViewError, match=r"common\.sim\.field"):
        render_ground_view(texture, fisheye, *nadir_camera_pose(0.0, 0.0, 1.5))
    with pytest.raises(GroundViewError, match="fisheye"):
        hover_flight(n_frames=3, camera=fisheye).frame(1)
