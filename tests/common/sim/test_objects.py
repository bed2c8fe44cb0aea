"""The object-scale simulation: the tabletop part, its clutter, and flights within the motion limits."""

from __future__ import annotations

import numpy as np
import pytest

from common.errors import InputError
from common.localization.pose import rotation_angle_rad
from common.sim.objects import (
    MAX_STEP_M,
    MAX_STEP_RAD,
    OBJECT_CENTRE_M,
    kidnap,
    object_camera,
    object_flight,
    offset_pose,
    random_kidnap,
    render_camera_flight,
    rendered_object_flight,
    tabletop_model,
    tabletop_scene,
)


def test_tabletop_part_is_object_scale_with_concave_parts_and_limbs() -> None:
    model = tabletop_model()
    assert 0.2 <= model.size_m <= 0.5
    assert int(model.edge_smooth.sum()) == 16  # the cylinder's sides: limbs only
    # the L-shaped top was triangulated: more faces than polygons given, its inner sides dropped
    top = np.isclose(model.face_offsets_m, 0.06) & np.isclose(model.face_normals[:, 2], 1.0)
    assert top.sum() >= 4
    scene = tabletop_scene()
    assert scene.n_edges > model.n_edges  # clutter that is not in the model
    assert tabletop_scene(with_part=False).n_edges == scene.n_edges - model.n_edges


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_flights_respect_the_limits_and_are_deterministic(seed: int) -> None:
    flight = object_flight(300, seed=seed)
    steps_m = np.linalg.norm(np.diff(flight.p_world_camera_m, axis=0), axis=1)
    steps_rad = rotation_angle_rad(flight.R_world_camera[1:], flight.R_world_camera[:-1])
    assert steps_m.max() <= MAX_STEP_M and steps_rad.max() <= MAX_STEP_RAD
    assert steps_m.max() > 0.5 * MAX_STEP_M  # and it does move
    distance = np.linalg.norm(flight.p_world_camera_m - np.asarray(OBJECT_CENTRE_M), axis=1)
    assert distance.min() >= 0.4 and distance.max() <= 1.0
    # the part stays in front of the camera, near the image centre
    to_part = np.asarray(OBJECT_CENTRE_M) - flight.p_world_camera_m
    along = np.einsum("ti,ti->t", to_part, flight.R_world_camera[:, :, 2]) / distance
    assert along.min() > np.cos(np.radians(15.0))
    again = object_flight(300, seed=seed)
    assert np.array_equal(again.p_world_camera_m, flight.p_world_camera_m)
    assert np.allclose(np.einsum("tij,tkj->tik", flight.R_world_camera, flight.R_world_camera), np.eye(3))
    assert np.allclose(np.linalg.det(flight.R_world_camera), 1.0)


def test_kidnap_teleports_from_a_frame_on() -> None:
    flight = object_flight(10, seed=0)
    moved = kidnap(flight, 4, [0.1, 0.0, 0.0], [0.0, 0.0, np.radians(10.0)])
    assert np.array_equal(moved.p_world_camera_m[:4], flight.p_world_camera_m[:4])
    assert np.allclose(moved.p_world_camera_m[4:] - flight.p_world_camera_m[4:], [0.1, 0.0, 0.0])
    assert np.allclose(
        rotation_angle_rad(moved.R_world_camera[4:], flight.R_world_camera[4:]), np.radians(10.0)
    )
    with pytest.raises(InputError):
        kidnap(flight, 0, [0, 0, 0], [0, 0, 0])


@pytest.mark.parametrize("seed", [0, 7])
def test_random_offsets_have_exactly_the_asked_size_and_depend_on_the_seed(seed: int) -> None:
    flight = object_flight(10, seed=0)
    start = offset_pose(flight.pose(0), 0.03, np.radians(5.0), seed)
    assert np.isclose(np.linalg.norm(start.p_world_camera_m - flight.p_world_camera_m[0]), 0.03)
    assert np.isclose(rotation_angle_rad(start.R_world_camera, flight.R_world_camera[0]), np.radians(5.0))
    other = offset_pose(flight.pose(0), 0.03, np.radians(5.0), seed + 1)
    assert not np.allclose(other.p_world_camera_m, start.p_world_camera_m)
    moved = random_kidnap(flight, 4, 0.1, np.radians(10.0), seed)
    assert np.array_equal(moved.p_world_camera_m[:4], flight.p_world_camera_m[:4])
    shifts = np.linalg.norm(moved.p_world_camera_m[4:] - flight.p_world_camera_m[4:], axis=1)
    assert np.allclose(shifts, 0.1)
    turns = rotation_angle_rad(moved.R_world_camera[4:], flight.R_world_camera[4:])
    assert np.allclose(turns, np.radians(10.0))
    tail = moved.part(4, 8)
    assert tail.n_frames == 4 and np.array_equal(tail.times_s, flight.times_s[4:8])
    assert np.array_equal(tail.pose(0).R_world_camera, moved.R_world_camera[4])


def test_rendered_object_flight_is_the_flight_and_its_seeded_frames() -> None:
    flight, images = rendered_object_flight(3, 2)
    assert np.array_equal(flight.p_world_camera_m, object_flight(3, seed=2).p_world_camera_m)
    again = render_camera_flight(tabletop_scene(), flight, object_camera(), rng=np.random.default_rng(2))
    assert len(images) == 3 and all(np.array_equal(a, b) for a, b in zip(images, again, strict=True))


def test_frames_show_the_part_and_are_reproducible() -> None:
    flight = object_flight(2, seed=0)
    camera = object_camera()
    a = list(render_camera_flight(tabletop_scene(), flight, camera, rng=np.random.default_rng(5)))
    b = list(render_camera_flight(tabletop_scene(), flight, camera, rng=np.random.default_rng(5)))
    empty = list(
        render_camera_flight(tabletop_scene(with_part=False), flight, camera, rng=np.random.default_rng(5))
    )
    assert a[0].shape == (480, 640) and np.array_equal(a[0], b[0])
    assert np.mean(np.abs(a[0].astype(int) - empty[0].astype(int)) > 20) > 0.03  # the part covers the centre
