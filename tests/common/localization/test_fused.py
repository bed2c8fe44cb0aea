"""The compiled weighting pass agrees with the general numpy path particle by particle."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import Distortion, DistortionModel
from common.localization.fused import _cloud_frustum, _exp_parts, fused_applies
from common.localization.pose import CameraPose, perturb
from common.localization.projection import frustum_edges
from common.localization.scoring import ScoringMethod, ScoringSettings, with_oriented_distances
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings
from common.sim.objects import (
    object_camera,
    object_flight,
    render_camera_flight,
    tabletop_model,
    tabletop_scene,
)


@pytest.mark.parametrize("method", [m for m in ScoringMethod if m is not ScoringMethod.NEAREST_EDGE])
@pytest.mark.parametrize("hidden_line_removal", [True, False])
def test_fused_weighting_matches_the_numpy_path(method: ScoringMethod, hidden_line_removal: bool) -> None:
    flight = object_flight(3, seed=4)
    camera = object_camera()
    image = list(render_camera_flight(tabletop_scene(), flight, camera, rng=np.random.default_rng(4)))[2]
    config = TrackerSettings(scoring=ScoringSettings(method=method), hidden_line_removal=hidden_line_removal)
    fused = ModelTracker(tabletop_model(), camera, config)
    general = ModelTracker(
        tabletop_model(), camera, replace(config, fused_weighting=False, chunk_particles=64)
    )
    rng = np.random.default_rng(0)
    n = 300  # poses near the truth and far off it (partly out of view, some behind the near plane)
    spread = np.repeat([0.003, 0.05, 0.3], n // 3)[:, None]
    positions = flight.p_world_camera_m[2] + rng.normal(size=(n, 3)) * spread
    rotations = perturb(
        np.repeat(flight.R_world_camera[2][None], n, axis=0), rng.normal(size=(n, 3)) * spread
    )
    edges = fused.edges(image)
    visible = fused._visible(CameraPose(flight.p_world_camera_m[2], flight.R_world_camera[2]))
    # the whole set (faces seen by some poses only: back-face culling per pose) and the close poses alone
    for cloud in (slice(None), slice(0, n // 3)):
        for coarseness, expected_points in ((1.0, 0), (1.0, 400), (2.5, 0)):
            args = (positions[cloud], rotations[cloud], edges, visible, coarseness, expected_points)
            a = fused.log_likelihood(*args)
            b = general.log_likelihood(*args)
            # exact for counts; g(d) within 1e-6 of the exponential
            tolerance = 1e-5 if method is ScoringMethod.NEAREST_EDGE_DT else 1e-9
            assert np.allclose(a, b, atol=tolerance), np.abs(a - b).max()
            assert np.ptp(b) > 0.5  # the poses differ: the comparison is not between constants


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-300.0, 0.0, width=32), min_size=1, max_size=70))
def test_compiled_exponential_is_within_a_millionth_of_numpy(values: list[float]) -> None:
    x = np.asarray(values, dtype=np.float32)
    # as the kernel combines them: the mantissa times the float32 whose bits are 2^n
    mantissas, bits = zip(*(_exp_parts(v) for v in x), strict=True)
    out = np.array(mantissas, np.float32) * np.array(bits, np.int32).view(np.float32)
    exact = np.exp(np.maximum(x.astype(np.float64), -87.0))  # below -87: exp(-87), a normal float32
    assert np.all(np.abs(out - exact) <= 1e-6 * exact), np.max(np.abs(out - exact) / exact)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 0.5), st.floats(0.0, 1.0), st.integers(0, 2**31 - 1))
def test_cloud_frustum_keeps_every_edge_some_camera_sees(shift_m: float, turn_rad: float, seed: int) -> None:
    # the kernel tests the frustum once per cloud, grown by the cloud's spread; every edge whose sphere one
    # of the cameras keeps (the general path's per-camera test) must be among its candidates
    flight = object_flight(2, seed=seed % 1000)
    tracker = ModelTracker(tabletop_model(), object_camera())
    rng = np.random.default_rng(seed)
    n = 20
    positions = flight.p_world_camera_m[1] + rng.normal(size=(n, 3)) * shift_m
    rotations = perturb(
        np.repeat(flight.R_world_camera[1][None], n, axis=0), rng.normal(size=(n, 3)) * turn_rad
    )
    R_cw = np.ascontiguousarray(np.swapaxes(rotations, 1, 2))
    seen = frustum_edges(tracker.samples, R_cw, positions, tracker.camera).any(axis=0)
    candidates = _cloud_frustum(R_cw, np.ascontiguousarray(positions), tracker.fused, 0.05)
    assert seen.any()
    assert not np.any(seen & ~candidates)
    if shift_m == 0.0 and turn_rad == 0.0:  # one pose: the same test, but for an edge within its margin
        assert candidates.sum() <= seen.sum() + 1


def test_fused_weighting_leaves_what_it_cannot_compute_to_the_general_path() -> None:
    camera = object_camera()
    image = np.zeros((camera.height, camera.width), dtype=np.uint8)
    image[100:300, 200:400] = 200
    tracker = ModelTracker(tabletop_model(), camera)
    edges = tracker.edges(image)
    params = ScoringSettings()
    assert fused_applies(camera, edges, params)
    assert not fused_applies(camera, edges, replace(params, method=ScoringMethod.NEAREST_EDGE))
    assert not fused_applies(camera, with_oriented_distances(edges), params)
    lens = replace(camera, distortion=Distortion(DistortionModel.RADTAN, (0.1, 0.0, 0.0, 0.0, 0.0)))
    assert not fused_applies(lens, edges, params)


def test_building_a_tracker_compiles_the_pass_its_frames_use() -> None:
    # a service builds its tracker before it subscribes: the first frame must not meet a cold compile
    from common.localization.fused import _edge_sums

    flight = object_flight(2, seed=1)
    camera = object_camera()
    tracker = ModelTracker(tabletop_model(), camera)
    compiled = len(_edge_sums.signatures)
    assert compiled >= 1
    image = next(render_camera_flight(tabletop_scene(), flight, camera, rng=np.random.default_rng(1)))
    tracker.log_likelihood(flight.p_world_camera_m[:1], flight.R_world_camera[:1], tracker.edges(image), None)
    assert len(_edge_sums.signatures) == compiled  # the frame's call found its specialisation built
