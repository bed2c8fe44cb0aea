"""Rendering of the 3D scene (z-buffer, near-plane clipping, shading, degradations) and the default flight."""

from __future__ import annotations

import numpy as np
import pytest

from common.camera import CameraModel
from common.errors import InputError
from common.localization.model import build_scene
from common.localization.office import default_scene
from common.sim.scene import (
    DEFAULT_FLIGHT_RENDER,
    RenderOptions,
    default_flight,
    face_shades,
    rasterize_scene,
    render_scene,
)

CAMERA = CameraModel.from_hfov(160, 120, 70.0)


def _wall_with_decal():
    """A wall at x = 4 facing the origin, and a darker decal 1 cm in front of it (y, z in [-0.5, 0.5])."""
    vertices = [
        [4.0, 3.0, -2.0], [4.0, -3.0, -2.0], [4.0, -3.0, 2.0], [4.0, 3.0, 2.0],
        [3.99, 0.5, -0.5], [3.99, -0.5, -0.5], [3.99, -0.5, 0.5], [3.99, 0.5, 0.5],
    ]  # fmt: skip
    return build_scene(vertices, [[0, 1, 2, 3], [4, 5, 6, 7]], [0.8, 0.2])


def test_z_buffer_shows_the_nearest_face_with_its_true_depth() -> None:
    layers = rasterize_scene(_wall_with_decal(), np.zeros(6), CAMERA)
    cy, cx = CAMERA.shape[0] // 2, CAMERA.shape[1] // 2
    assert layers.face_id[cy, cx] == 1  # the decal in front of the wall
    assert 1.0 / layers.inverse_depth[cy, cx] == pytest.approx(3.99, abs=1e-6)
    # the wall around it (its top side projects to row 2.37: row 2's centre is above it, off the wall)
    assert layers.face_id[5, 5] == 0 and layers.face_id[2, 2] == -1
    # depth along the optical axis is constant on a wall facing the camera
    assert np.allclose(1.0 / layers.inverse_depth[layers.face_id == 0], 4.0)
    # the decal covers its projected square: half-size 0.5 m at 3.99 m
    half_px = CAMERA.fx * 0.5 / 3.99
    assert (layers.face_id == 1).sum() == pytest.approx((2 * half_px) ** 2, rel=0.1)


def test_faces_behind_or_facing_away_are_not_drawn() -> None:
    turned = np.array([0.0, 0.0, 0.0, 0.0, 0.0, np.pi])  # looking away from the wall
    assert np.all(rasterize_scene(_wall_with_decal(), turned, CAMERA).face_id == -1)
    behind_wall = np.array([5.0, 0.0, 0.0, 0.0, 0.0, np.pi])  # behind the wall, looking at its back
    assert np.all(rasterize_scene(_wall_with_decal(), behind_wall, CAMERA).face_id == -1)


def test_faces_crossing_the_near_plane_are_clipped_not_dropped() -> None:
    floor = build_scene([[-5, -5, -1], [5, -5, -1], [5, 5, -1], [-5, 5, -1]], [[0, 1, 2, 3]], [0.5])
    layers = rasterize_scene(floor, np.zeros(6), CAMERA)
    # the lower half of the image sees the floor, the upper half nothing (horizon at the centre row)
    assert np.all(layers.face_id[-10:] == 0)
    assert np.all(layers.face_id[:50] == -1)
    row = CAMERA.shape[0] - 1
    depth = 1.0 / layers.inverse_depth[row, CAMERA.shape[1] // 2]
    assert depth == pytest.approx(CAMERA.fy / (row - CAMERA.cy), rel=1e-6)


def test_shading_gives_every_box_side_its_own_grey_level() -> None:
    office = default_scene()
    shades = face_shades(office, RenderOptions())
    assert np.all((shades >= 0.0) & (shades <= 255.0))
    # the four sides of one box (same albedo, normals +-x, +-y) differ
    box_sides = [f for f in range(office.n_faces) if office.face_albedo[f] == 0.45][:4]
    assert len(set(np.round(shades[box_sides], 6))) == 4


def test_rendering_is_deterministic_per_seed_and_degrades_as_asked() -> None:
    office = default_scene()
    pose = np.array([5.0, 4.0, 1.5, 0.0, 0.0, 0.3])
    clean = render_scene(office, pose, CAMERA)
    a = render_scene(office, pose, CAMERA, DEFAULT_FLIGHT_RENDER, np.random.default_rng(1))
    b = render_scene(office, pose, CAMERA, DEFAULT_FLIGHT_RENDER, np.random.default_rng(1))
    assert clean.dtype == np.uint8 and clean.shape == CAMERA.shape
    assert np.array_equal(a, b)
    assert 0.5 < np.abs(a.astype(float) - clean).mean() < 10.0
    with pytest.raises(InputError, match="rng"):
        render_scene(office, pose, CAMERA, RenderOptions(noise_sigma=1.0))


def test_default_flight_has_consistent_rates_and_stays_inside_the_room() -> None:
    flight = default_flight()
    assert flight.n_frames == 300
    dt = np.diff(flight.times_s)
    velocity_fd = np.diff(flight.states[:, :3], axis=0) / dt[:, None]
    velocity_mid = 0.5 * (flight.velocities_world_m_s[1:] + flight.velocities_world_m_s[:-1])
    assert np.allclose(velocity_fd, velocity_mid, atol=5e-3)
    angle_fd = np.angle(np.exp(1j * np.diff(flight.states[:, 3:], axis=0))) / dt[:, None]
    rate_mid = 0.5 * (flight.euler_rates_rad_s[1:] + flight.euler_rates_rad_s[:-1])
    assert np.allclose(angle_fd, rate_mid, atol=5e-3)
    assert np.all((flight.states[:, 0] > 1.0) & (flight.states[:, 0] < 9.0))
    assert np.all((flight.states[:, 1] > 1.0) & (flight.states[:, 1] < 7.0))
    assert np.all((flight.states[:, 2] > 1.0) & (flight.states[:, 2] < 2.0))
