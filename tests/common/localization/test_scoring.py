"""Paper B's scorings on rendered images: the true pose ranks first; the DT fast path ranks like the normal
search; the formulas on hand-made inputs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.localization.model import SceneModel
from common.localization.projection import ProjectedSamples, project_samples, sample_edges
from common.localization.scoring import (
    ORIENTATION_BINS,
    ImageEdges,
    ScoringMethod,
    ScoringSettings,
    extract_image_edges,
    klein_murray_log_weight,
    nearest_edge_log_weight,
    normal_search_distances,
    normal_weight,
    orientation_bins,
    per_edge_log_weight,
    score_particles,
    with_oriented_distances,
)
from common.sim.scene import DEFAULT_FLIGHT_RENDER, render_scene


def _random_true_pose(draw_unit: list[float]) -> np.ndarray:
    """A pose inside the office's free middle, level within 5 deg, any heading."""
    a, b, c, d, e, f = draw_unit
    return np.array(
        [
            3.0 + 4.0 * a,
            2.5 + 3.0 * b,
            1.0 + c,
            np.radians(10 * d - 5),
            np.radians(10 * e - 5),
            np.pi * (2 * f - 1),
        ]
    )


unit = st.floats(0.0, 1.0, allow_nan=False)
direction = st.tuples(*(st.floats(-1.0, 1.0, allow_nan=False) for _ in range(3))).filter(
    lambda v: float(np.linalg.norm(v)) > 0.1
)


@settings(
    max_examples=12,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    pose_unit=st.lists(unit, min_size=6, max_size=6),
    directions=st.lists(direction, min_size=6, max_size=6),
    position_offset_m=st.floats(0.1, 0.3),
    angle_offset_deg=st.floats(2.0, 6.0),
    seed=st.integers(0, 2**16),
)
def test_every_scoring_ranks_the_true_pose_above_perturbed_poses(
    office: SceneModel,
    small_camera: CameraModel,
    pose_unit: list[float],
    directions: list[tuple[float, float, float]],
    position_offset_m: float,
    angle_offset_deg: float,
    seed: int,
) -> None:
    truth = _random_true_pose(pose_unit)
    image = render_scene(office, truth, small_camera, DEFAULT_FLIGHT_RENDER, np.random.default_rng(seed))
    samples = sample_edges(office, points_per_edge=8)
    seen_edges = int((project_samples(samples, truth, small_camera).valid[0].sum(axis=1) > 0).sum())
    assume(seen_edges >= 12)  # not a bare wall filling the view
    perturbed = []
    for i, v in enumerate(directions):
        unit_v = np.asarray(v) / np.linalg.norm(v)
        offset = np.zeros(6)
        if i % 2 == 0:
            offset[:3] = position_offset_m * unit_v
        else:
            offset[3:] = np.radians(angle_offset_deg) * unit_v
        perturbed.append(truth + offset)
    states = np.vstack([truth, perturbed])
    edges = extract_image_edges(image)
    projected = project_samples(samples, states, small_camera, with_normals=True)
    for method in ScoringMethod:
        result = score_particles(projected, edges, ScoringSettings(method=method))
        assert np.all(result.log_weight[0] > result.log_weight[1:]), method
        assert np.all((result.fit >= 0.0) & (result.fit <= 1.0))


def _ranks(x: np.ndarray) -> np.ndarray:
    return np.argsort(np.argsort(x)).astype(float)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_distance_transform_fast_path_ranks_particles_like_the_normal_search(
    office: SceneModel, small_camera: CameraModel, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    truth = _random_true_pose(list(rng.uniform(0.0, 1.0, 6)))
    image = render_scene(office, truth, small_camera, DEFAULT_FLIGHT_RENDER, rng)
    cloud = truth + rng.uniform(-1.0, 1.0, (150, 6)) * [0.3, 0.3, 0.3, 0.1, 0.1, 0.1]
    states = np.vstack([truth, cloud])
    edges = extract_image_edges(image)
    projected = project_samples(sample_edges(office), states, small_camera, with_normals=True)
    exact = score_particles(projected, edges, ScoringSettings(method=ScoringMethod.NEAREST_EDGE)).log_weight
    fast = score_particles(projected, edges, ScoringSettings(method=ScoringMethod.NEAREST_EDGE_DT)).log_weight
    spearman = np.corrcoef(_ranks(exact), _ranks(fast))[0, 1]
    assert spearman > 0.9
    assert np.argmax(exact) == 0 and np.argmax(fast) == 0
    # the nearest edge pixel in any direction is never farther than the one along the normal
    assert np.all(fast >= exact - 1e-9)


def _vertical_line_edges(column: int, width: int = 64, height: int = 48) -> ImageEdges:
    image = np.zeros((height, width), dtype=np.uint8)
    image[:, column:] = 200
    return extract_image_edges(image)


def _one_point(u: float, v: float, normal: tuple[float, float], width: int = 64) -> ProjectedSamples:
    shape = (1, 1, 1)
    return ProjectedSamples(
        u_px=np.full(shape, u, dtype=np.float32),
        v_px=np.full(shape, v, dtype=np.float32),
        valid=np.ones(shape, dtype=bool),
        pixel_index=np.full(shape, round(v) * width + round(u), dtype=np.int32),
        edge_ids=np.zeros(1, dtype=np.int64),
        normal_u=np.full(shape, normal[0], dtype=np.float32),
        normal_v=np.full(shape, normal[1], dtype=np.float32),
    )


def test_normal_search_walks_along_the_normal_up_to_its_maximum_length() -> None:
    edges = _vertical_line_edges(40)
    edge_columns = np.flatnonzero(edges.edge_map[24])
    assert edge_columns.size > 0
    nearest = int(edge_columns.min())
    along = normal_search_distances(_one_point(nearest - 5, 24, (1.0, 0.0)), edges, max_normal_px=10)
    assert along[0, 0, 0] == pytest.approx(5.0)
    # searching both ways: a normal pointing away finds the same edge behind
    assert normal_search_distances(_one_point(nearest - 5, 24, (-1.0, 0.0)), edges, 10)[0, 0, 0] == 5.0
    # parallel to the edge: nothing on the normal
    assert np.isinf(normal_search_distances(_one_point(nearest - 5, 24, (0.0, 1.0)), edges, 10)[0, 0, 0])
    # beyond the maximum normal length: dropped
    assert np.isinf(normal_search_distances(_one_point(nearest - 5, 24, (1.0, 0.0)), edges, 4)[0, 0, 0])


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_normal_search_ignores_culled_points_with_nan_coordinates() -> None:
    """Regression: culled points (nan pixel coordinates) were cast to int before being masked out."""
    edges = _vertical_line_edges(40)
    # one valid point 5 px left of the edge along +u, one culled point with nan coordinates
    u_px = np.array([[[35.0, np.nan]]], dtype=np.float32)
    v_px = np.array([[[24.0, np.nan]]], dtype=np.float32)
    samples = ProjectedSamples(
        u_px=u_px,
        v_px=v_px,
        valid=np.array([[[True, False]]]),
        pixel_index=np.array([[[24 * 64 + 35, edges.width * edges.height]]], dtype=np.int32),
        edge_ids=np.zeros(1, dtype=np.int64),
        normal_u=np.array([[[1.0, np.nan]]], dtype=np.float32),
        normal_v=np.array([[[0.0, np.nan]]], dtype=np.float32),
    )
    distance = normal_search_distances(samples, edges, max_normal_px=10)[0, 0]
    assert np.isfinite(distance[0]) and np.isinf(distance[1])


def test_scoring_formulas_on_hand_made_counts() -> None:
    # Klein & Murray: k a / v
    assert klein_murray_log_weight(np.array([3.0]), np.array([4.0]), k=8.0)[0] == pytest.approx(6.0)
    # per edge: k a/v + lambda mean_j a_j/v_j over edges with v_j > 0
    a_j = np.array([[2.0, 0.0, 1.0]])
    v_j = np.array([[2.0, 0.0, 4.0]])
    expected = 10.0 * 3.0 / 6.0 + 4.0 * (1.0 + 0.25) / 2
    assert per_edge_log_weight(a_j, v_j, k=10.0, lambda_per_edge=4.0)[0] == pytest.approx(expected)
    # g(d) = exp(-d^2 / 2 sigma^2), zero beyond the maximum
    g = normal_weight(np.array([0.0, 2.0, 11.0, np.inf], dtype=np.float32), sigma_px=2.0, max_normal_px=10)
    assert np.allclose(g, [1.0, np.exp(-0.5), 0.0, 0.0])
    # nearest edge: l_n = mean over a line's visible points, W = alpha exp(k mean_n l_n)
    weights = np.array([[[1.0, 0.5], [0.2, 0.0]]], dtype=np.float32)
    valid = np.array([[[True, True], [True, False]]])
    log_w, mean_l = nearest_edge_log_weight(weights, valid, k=2.0, alpha=3.0)
    assert mean_l[0] == pytest.approx((0.75 + 0.2) / 2)
    assert log_w[0] == pytest.approx(np.log(3.0) + 2.0 * (0.75 + 0.2) / 2)


def test_images_are_validated() -> None:
    with pytest.raises(InputError, match="uint8"):
        extract_image_edges(np.zeros((20, 20), dtype=np.float32))
    with pytest.raises(InputError, match="grey image"):
        extract_image_edges(np.zeros((20, 20, 3), dtype=np.uint8))


def test_oriented_distances_see_only_edges_of_the_normal_direction() -> None:
    image = np.full((60, 80), 60, dtype=np.uint8)
    image[:, 40:] = 200  # a vertical edge at column 39/40 (its normal: along x)
    image[:10, :] = 120  # a horizontal edge at row 9/10 (its normal: along y)
    edges = with_oriented_distances(extract_image_edges(image, with_gradients=True))
    assert edges.oriented_lookup is not None
    assert edges.oriented_lookup.shape == (ORIENTATION_BINS, 60 * 80 + 1)
    x_bin = int(orientation_bins(np.array([1.0]), np.array([0.0]))[0])
    y_bin = int(orientation_bins(np.array([0.0]), np.array([1.0]))[0])
    assert x_bin != y_bin
    # a point 3 px right of the vertical edge, 1 px below the horizontal one
    index = 11 * 80 + 42
    assert edges.oriented_lookup[x_bin, index] <= 3.5  # the vertical edge, 2-3 px away
    assert edges.oriented_lookup[y_bin, index] <= 2.0  # the horizontal edge, about 1 px away
    beside = 11 * 80 + 5  # next to the horizontal edge, 34 px from the vertical one
    assert edges.distance_px.ravel()[beside] <= 2.0
    assert edges.oriented_lookup[x_bin, beside] >= 30.0  # an edge of the other direction does not count
    far = 40 * 80 + 70  # 30 px right of the vertical edge, 30 px below the horizontal one
    assert edges.oriented_lookup[x_bin, far] >= 25.0
    assert edges.distance_px.ravel()[far] >= 25.0
    assert edges.oriented_lookup[y_bin, far] >= 25.0
    with pytest.raises(InputError):
        with_oriented_distances(extract_image_edges(image))  # no gradients


def test_orientation_bins_of_culled_points_are_zero_without_warnings() -> None:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bins = orientation_bins(np.array([np.nan, 1.0, 0.0]), np.array([np.nan, 0.0, -1.0]))
    assert bins.tolist() == [0, 0, ORIENTATION_BINS // 2]
