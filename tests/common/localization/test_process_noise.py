"""Process noise in pixels per frame (:mod:`common.localization.process_noise`): it follows the model's
distance, the focal length and the stream, adapts within its bounds, and the tracker's cloud spreads by the
same image motion whatever the scale of the scene."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.localization.pose import CameraPose
from common.localization.process_noise import (
    MIN_APPARENT_RADIUS_PX,
    NoiseSettings,
    NoiseState,
    adapt,
    observe_interval,
    pixel_scale,
    residual_px,
)
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings
from common.sim.objects import object_camera, object_flight, scaled_scene, tabletop_model

distances = st.floats(0.05, 50.0)
focals = st.floats(100.0, 3000.0)


def _camera(f: float) -> CameraModel:
    return CameraModel(width=640, height=480, fx=f, fy=f, cx=320.0, cy=240.0)


@settings(max_examples=60, deadline=None)
@given(d=distances, f=focals, k=st.floats(0.2, 5.0), px=st.floats(0.1, 20.0))
def test_sideways_noise_moves_the_image_by_its_pixels(d: float, f: float, k: float, px: float) -> None:
    scale = pixel_scale(d, _camera(f), 0.1 * d)
    # a point d ahead, the camera moved sideways by the noise's sigma: the point moves px pixels
    position, rotation = scale.sigmas(px)
    assert np.isclose(f * position[0] / d, px, rtol=1e-9)
    assert np.isclose(f * rotation[0], px, rtol=1e-9)  # a turn of 1/f rad moves the image a pixel
    # proportional to distance, inversely to focal length
    farther = pixel_scale(k * d, _camera(f), 0.1 * d * k)
    assert np.isclose(farther.lateral_m, k * scale.lateral_m, rtol=1e-9)
    assert np.isclose(farther.depth_m, k * scale.depth_m, rtol=1e-9)  # the same model scaled with it
    longer = pixel_scale(d, _camera(k * f), 0.1 * d)
    assert np.isclose(longer.lateral_m, scale.lateral_m / k, rtol=1e-9)


@settings(max_examples=60, deadline=None)
@given(d=distances, f=focals, radius=st.floats(0.001, 100.0), px=st.floats(0.1, 20.0))
def test_depth_and_roll_noise_grow_the_outline_by_at_most_its_pixels(
    d: float, f: float, radius: float, px: float
) -> None:
    scale = pixel_scale(d, _camera(f), radius)
    position, rotation = scale.sigmas(px)
    # the outline in view: the model's, or the image's where the model overfills it
    outline_px = min(f * radius / d, 0.5 * np.hypot(640, 480))
    # moving along the axis by the depth sigma grows an outline of radius r px by r dz / d: at most px (less
    # for a model smaller than MIN_APPARENT_RADIUS_PX); rolling by the roll sigma moves it r droll <= px
    assert outline_px * position[2] / d <= px * (1.0 + 1e-9)
    assert outline_px * rotation[2] <= px * (1.0 + 1e-9)
    if outline_px >= MIN_APPARENT_RADIUS_PX:
        assert np.isclose(outline_px * position[2] / d, px, rtol=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    residuals=st.lists(st.floats(0.0, 1e4), min_size=1, max_size=40),
    initial=st.floats(0.1, 10.0),
)
def test_adapted_noise_stays_within_its_bounds(residuals: list[float], initial: float) -> None:
    cfg = NoiseSettings(initial_px=initial)
    state = NoiseState.initial(cfg)
    for r in residuals:
        state = adapt(state, r, cfg)
        assert cfg.floor_px <= state.noise_px <= cfg.ceiling_px


def test_noise_follows_the_residual_up_and_back_down() -> None:
    cfg = NoiseSettings()
    state = NoiseState.initial(cfg)
    for _ in range(30):
        state = adapt(state, 4.0, cfg)
    assert np.isclose(state.noise_px, min(cfg.gain * 4.0, cfg.ceiling_px), rtol=0.02)
    for _ in range(30):
        state = adapt(state, 0.1, cfg)
    assert state.noise_px == cfg.floor_px


def test_a_skipped_frame_spans_its_elapsed_intervals_and_leaves_the_interval() -> None:
    cfg = NoiseSettings()
    state = observe_interval(NoiseState.initial(cfg), 0.05, cfg)
    for _ in range(5):
        state = observe_interval(state, 0.05, cfg)
    assert np.isclose(state.last_frames, 1.0) and np.isclose(state.frame_interval_s or 0.0, 0.05)
    skipped = observe_interval(state, 0.15, cfg)  # two frames skipped
    assert np.isclose(skipped.last_frames, 3.0) and skipped.frame_interval_s == state.frame_interval_s
    huge = observe_interval(state, 100.0, cfg)
    assert huge.last_frames == cfg.max_gap_frames


def test_residual_is_the_image_displacement() -> None:
    camera = _camera(500.0)
    pose = CameraPose(np.zeros(3), np.eye(3))
    points = np.array([[0.0, 0.0, 2.0], [0.1, -0.1, 2.0]])
    moved = CameraPose(np.array([0.004, 0.0, 0.0]), np.eye(3))  # 4 mm at 2 m: 1 px
    assert np.isclose(residual_px(pose, moved, points, camera), 1.0)
    # points beside, behind or right in front of the camera (inside a room) do not count
    beside = np.vstack([points, [[5.0, 0.0, 0.05], [0.0, 0.0, -1.0], [0.0, 0.0, 0.01]]])
    assert np.isclose(residual_px(pose, moved, beside, camera), 1.0)


def test_the_cloud_spreads_by_the_same_pixels_at_any_scale() -> None:
    # the same view of the part at 1x and 10x (camera 10x farther): the cloud's image spread is the same
    flight = object_flight(2, seed=0)
    spreads = []
    for scale in (1.0, 10.0):
        tracker = ModelTracker(scaled_scene(tabletop_model(), scale), object_camera(), TrackerSettings())
        pose = CameraPose(scale * flight.p_world_camera_m[0], flight.R_world_camera[0])
        state = tracker.start(pose)
        state = replace(state, process_noise=observe_interval(state.process_noise or
                        NoiseState.initial(tracker.config.noise), 1 / 30, tracker.config.noise))  # fmt: skip
        moved = tracker.predict(state, 1 / 30, np.random.default_rng(0))
        centre = tracker.scene.centre_world_m
        shifts = [
            residual_px(pose, CameraPose(p, R), centre[None], tracker.camera)
            for p, R in zip(moved.positions_m, moved.rotations, strict=True)
        ]
        spreads.append(float(np.sqrt(np.mean(np.square(shifts)))))
    assert np.isclose(spreads[0], spreads[1], rtol=0.05)
    # about the configured pixels per frame (sideways and turn both move the centre: ~sqrt(2) x 2 px per axis)
    assert 1.0 <= spreads[0] <= 8.0
