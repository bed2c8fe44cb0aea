"""Projection of model edges into particles' cameras: hand-computed cameras, culling, batching."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.localization.model import SceneModel, build_scene
from common.localization.pose import perturb
from common.localization.projection import (
    camera_poses,
    project_pose_samples,
    project_samples,
    sample_edges,
)
from common.localization.projection_matrices import projection_matrices

CAMERA = CameraModel(width=320, height=240, fx=200.0, fy=210.0, cx=159.5, cy=119.5)


def _quad_scene(corners: list[list[float]], towards: list[float]) -> SceneModel:
    corners_arr = np.asarray(corners, dtype=float)
    normal = np.cross(corners_arr[1] - corners_arr[0], corners_arr[2] - corners_arr[0])
    if normal @ np.asarray(towards) < 0:
        corners_arr = corners_arr[::-1]
    return build_scene(corners_arr, [[0, 1, 2, 3]], [0.5])


def _hand_pixels(points_world: np.ndarray, origin: np.ndarray, yaw_rad: float) -> np.ndarray:
    """Forward camera of a level body: optical axis = heading, image right = heading rotated -90 deg."""
    forward = np.array([np.cos(yaw_rad), np.sin(yaw_rad), 0.0])
    right = np.array([np.sin(yaw_rad), -np.cos(yaw_rad), 0.0])
    d = points_world - origin
    depth = d @ forward
    u = CAMERA.cx + CAMERA.fx * (d @ right) / depth
    v = CAMERA.cy - CAMERA.fy * d[:, 2] / depth
    return np.stack([u, v], axis=1)


@pytest.mark.parametrize(
    ("origin", "yaw_deg", "corners", "towards"),
    [
        ([0.0, 0.0, 0.0], 0.0, [[4, -1, -0.5], [4, 1, -0.5], [4, 1, 0.5], [4, -1, 0.5]], [-1, 0, 0]),
        ([1.0, 2.0, 0.5], 90.0, [[0, 6, 0], [2, 6, 0], [2, 6, 1.2], [0, 6, 1.2]], [0, -1, 0]),
    ],
)
def test_projection_matches_a_hand_computed_camera(
    origin: list[float], yaw_deg: float, corners: list[list[float]], towards: list[float]
) -> None:
    scene = _quad_scene(corners, towards)
    samples = sample_edges(scene, points_per_edge=4)
    state = np.array([*origin, 0.0, 0.0, np.radians(yaw_deg)])
    projected = project_samples(samples, state, CAMERA)
    assert projected.edge_ids.tolist() == [0, 1, 2, 3]
    assert projected.valid.all()
    expected = _hand_pixels(samples.points_world_m.reshape(-1, 3), np.asarray(origin), np.radians(yaw_deg))
    got = np.stack([projected.u_px[0].ravel(), projected.v_px[0].ravel()], axis=1)
    assert np.allclose(got, expected, atol=1e-3)
    # the flat pixel index points at the nearest pixel
    row, column = np.divmod(projected.pixel_index[0].ravel(), CAMERA.width)
    assert np.all(np.abs(column - expected[:, 0]) <= 0.5 + 1e-3)
    assert np.all(np.abs(row - expected[:, 1]) <= 0.5 + 1e-3)


def test_culling_drops_edges_behind_the_camera() -> None:
    behind = _quad_scene([[-4, -1, -0.5], [-4, 1, -0.5], [-4, 1, 0.5], [-4, -1, 0.5]], [1, 0, 0])
    projected = project_samples(sample_edges(behind), np.zeros(6), CAMERA)
    assert projected.edge_ids.size == 0
    assert not projected.valid.any()


def test_back_faces_are_culled() -> None:
    away = _quad_scene([[4, -1, -0.5], [4, 1, -0.5], [4, 1, 0.5], [4, -1, 0.5]], [1, 0, 0])
    projected = project_samples(sample_edges(away), np.zeros(6), CAMERA)
    assert projected.edge_ids.size == 0


def test_edges_crossing_the_near_plane_keep_only_their_points_in_front() -> None:
    floor = _quad_scene([[-5, -0.5, -1], [5, -0.5, -1], [5, 0.5, -1], [-5, 0.5, -1]], [0, 0, 1])
    samples = sample_edges(floor, points_per_edge=20)
    projected = project_samples(samples, np.zeros(6), CAMERA)
    lengthwise = [i for i, e in enumerate(projected.edge_ids) if abs(samples.directions_world[e, 0]) > 0.9]
    assert len(lengthwise) == 2
    for i in lengthwise:
        x = samples.points_world_m[projected.edge_ids[i], :, 0]
        valid = projected.valid[0, i]
        assert valid.any() and not valid.all()
        assert np.all(x[valid] > 0.05)
        assert np.all(~valid[x < 0.05])


def test_states_are_validated() -> None:
    samples = sample_edges(_quad_scene([[4, -1, -0.5], [4, 1, -0.5], [4, 1, 0.5], [4, -1, 0.5]], [-1, 0, 0]))
    with pytest.raises(InputError, match=r"\(P, 6\)"):
        project_samples(samples, np.zeros((3, 5)), CAMERA)
    with pytest.raises(InputError, match="finite"):
        project_samples(samples, np.full(6, np.nan), CAMERA)


coordinate = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=25, deadline=None)
@given(
    st.lists(
        st.tuples(coordinate, coordinate, coordinate, coordinate, coordinate, coordinate),
        min_size=2,
        max_size=6,
    )
)
def test_batched_projection_equals_one_particle_at_a_time(
    office: SceneModel, offsets: list[tuple[float, ...]]
) -> None:
    samples = sample_edges(office, points_per_edge=5)
    states = np.array([5.0, 4.0, 1.5, 0.0, 0.0, 0.0]) + np.asarray(offsets) * [2.0, 2.0, 0.5, 0.3, 0.3, 3.1]
    batch = project_samples(samples, states, CAMERA, with_normals=True)
    for p in range(states.shape[0]):
        single = project_samples(samples, states[p], CAMERA, with_normals=True)
        rows = np.searchsorted(batch.edge_ids, single.edge_ids)
        assert np.array_equal(batch.edge_ids[rows], single.edge_ids)
        # edges kept only for other particles have no valid points for this one
        others = np.setdiff1d(np.arange(batch.edge_ids.size), rows)
        assert not batch.valid[p, others].any()
        assert np.array_equal(batch.valid[p, rows], single.valid[0])
        ok = single.valid[0]
        assert np.allclose(batch.u_px[p, rows][ok], single.u_px[0][ok], atol=1e-3)
        assert np.allclose(batch.v_px[p, rows][ok], single.v_px[0][ok], atol=1e-3)
        assert batch.normal_u is not None and single.normal_u is not None
        assert np.allclose(batch.normal_u[p, rows][ok], single.normal_u[0][ok], atol=1e-4)


def test_one_pose_projection_is_the_batch_of_one(office: SceneModel) -> None:
    samples = sample_edges(office, points_per_edge=5)
    state = np.array([[5.0, 4.0, 1.5, 0.1, -0.05, 0.7]])
    R_camera_world, p_world_camera = camera_poses(state)
    one = project_pose_samples(samples, R_camera_world[0], p_world_camera[0], CAMERA, with_normals=True)
    batch = project_samples(samples, state, CAMERA, with_normals=True)
    assert one.valid.shape[0] == 1 and one.valid.any()
    for name in ("u_px", "v_px", "valid", "pixel_index", "edge_ids", "normal_u", "normal_v"):
        assert np.array_equal(
            getattr(one, name), getattr(batch, name), equal_nan=name.endswith(("_px", "_u", "_v"))
        ), name


def test_projection_goes_through_the_lens_and_keeps_lines_and_limbs_right() -> None:
    from common.camera import Distortion, DistortionModel
    from common.localization.pose import CameraPose

    # a standalone line (no face), a smooth edge between two faces, a sharp one
    vertices = [[-1, 2, -0.5], [1, 2, -0.5], [-1, 2, 0.5], [1, 2, 0.5], [1.4, 2.3, 0.5], [1.4, 2.3, -0.5]]
    scene = build_scene(
        vertices,
        [[0, 1, 3, 2], [1, 5, 4, 3]],
        [0.5, 0.5],
        lines=[[0, 5]],
        face_groups=[0, 0],
    )
    R_world_camera = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    pose = CameraPose(np.zeros(3), R_world_camera)
    distorted = CameraModel(
        640,
        480,
        500.0,
        498.0,
        321.0,
        238.0,
        Distortion(DistortionModel.RADTAN, (-0.2, 0.05, 0.001, -0.001, 0.0)),
    )
    samples = sample_edges(scene, 4)
    projected = project_pose_samples(samples, pose.R_camera_world, pose.p_world_camera_m, distorted)
    valid = projected.valid[0]
    points = samples.points_world_m[projected.edge_ids][valid]
    expected = distorted.project((points - pose.p_world_camera_m) @ pose.R_world_camera)
    got = np.stack([projected.u_px[0][valid], projected.v_px[0][valid]], axis=1)
    assert np.allclose(got, expected, atol=1e-2)
    # the smooth edge (both faces towards the camera) is not a silhouette: culled; the line is always kept
    smooth = int(np.flatnonzero(scene.edge_smooth)[0])
    line = int(np.flatnonzero(scene.edge_faces[:, 0] < 0)[0])
    assert smooth not in projected.edge_ids.tolist()
    assert line in projected.edge_ids.tolist()
    # folded the other way the second face turns away: the smooth edge is a limb (silhouette) and is kept
    vertices[4], vertices[5] = [0.0, 2.5, 0.5], [0.0, 2.5, -0.5]
    limb = build_scene(vertices, [[0, 1, 3, 2], [1, 5, 4, 3]], [0.5, 0.5], face_groups=[0, 0])
    folded = project_pose_samples(
        sample_edges(limb, 4), pose.R_camera_world, pose.p_world_camera_m, distorted
    )
    assert int(np.flatnonzero(limb.edge_smooth)[0]) in folded.edge_ids.tolist()


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 40), st.integers(0, 2**31 - 1))
def test_projection_matrices_are_k_r_and_minus_k_r_p(n: int, seed: int) -> None:
    # the compiled product behind both weighting paths: K R and -K R p, computed in float64, rounded once
    rng = np.random.default_rng(seed)
    R_cw = np.swapaxes(perturb(np.repeat(np.eye(3)[None], n, axis=0), rng.normal(size=(n, 3)) * 2.0), 1, 2)
    p = rng.normal(size=(n, 3)) * 5.0
    K = np.array([[CAMERA.fx, 0.0, CAMERA.cx], [0.0, CAMERA.fy, CAMERA.cy], [0.0, 0.0, 1.0]])
    KR, Kt = projection_matrices(R_cw, p, CAMERA)
    assert KR.dtype == Kt.dtype == np.float32 and KR.shape == (n, 3, 3) and Kt.shape == (n, 3, 1)
    KR64 = K @ R_cw
    assert np.allclose(KR, KR64, rtol=1e-6, atol=1e-4)
    assert np.allclose(Kt[:, :, 0], -np.einsum("pij,pj->pi", KR64, p), rtol=1e-6, atol=1e-3)
