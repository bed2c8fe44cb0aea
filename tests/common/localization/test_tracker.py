"""The model tracker on the object-scale simulation, without odometry: it locks from 30 mm / 5 deg, tracks,
notices when the object is gone (texture alone does not fool it), and recovers from a kidnap."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.localization.pose import CameraPose, rotation_angle_rad
from common.localization.refine import EdgeFit, match_fraction, oriented_offsets
from common.localization.scoring import extract_image_edges
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings, TrackerState, TrackingStatus
from common.localization.tracking import pose_errors_mm_deg, track_model
from common.sim.objects import (
    CameraFlight,
    bench_kidnap,
    kidnap,
    object_camera,
    object_flight,
    offset_pose,
    render_camera_flight,
    rendered_object_flight,
    tabletop_model,
    tabletop_scene,
)
from common.sim.scene import render_view


@pytest.fixture(scope="module")
def tracker() -> ModelTracker:
    return ModelTracker(tabletop_model(), object_camera(), TrackerSettings())


def _start(flight: CameraFlight, seed: int, mm: float = 30.0, deg: float = 5.0) -> CameraPose:
    return offset_pose(flight.pose(0), 1e-3 * mm, np.radians(deg), seed)


def _run(
    tracker: ModelTracker, flight: CameraFlight, images: list[np.ndarray], state: TrackerState, seed: int
) -> tuple[np.ndarray, np.ndarray, list[TrackingStatus], TrackerState]:
    states = list(track_model(tracker, images, flight.times_s, state, np.random.default_rng(seed)))
    pos, rot = pose_errors_mm_deg(states, flight.p_world_camera_m, flight.R_world_camera)
    return pos, rot, [s.status for s in states], states[-1]


@pytest.mark.parametrize("seed", [0, 3])
def test_locks_and_tracks_without_odometry_from_30mm_5deg(tracker: ModelTracker, seed: int) -> None:
    flight, images = rendered_object_flight(30, seed, tracker.camera)
    pos, rot, status, _ = _run(tracker, flight, images, tracker.start(_start(flight, seed)), seed)
    assert np.median(pos[3:]) <= 5.0 and np.median(rot[3:]) <= 0.5
    assert status[-10:] == [TrackingStatus.TRACKING] * 10


def test_object_gone_is_detected_and_tracking_resumes(tracker: ModelTracker) -> None:
    flight = object_flight(36, seed=1)
    world = tabletop_scene()
    clutter = tabletop_scene(with_part=False)
    rng = np.random.default_rng(1)
    images = [
        render_view(clutter if 12 <= i < 26 else world, R, p, tracker.camera, rng=rng)
        for i, (p, R) in enumerate(zip(flight.p_world_camera_m, flight.R_world_camera, strict=True))
    ]
    start = flight.pose(0)
    pos, _, status, state = _run(tracker, flight, images, tracker.start(start), 2)
    assert status[11] is TrackingStatus.TRACKING
    assert status[12] is TrackingStatus.SEARCHING  # the first frame without the part
    assert status[25] is TrackingStatus.LOST  # more than lost_frames bad frames in a row
    assert TrackingStatus.TRACKING not in status[12:26], "texture and clutter alone were taken for the part"
    assert status[-1] is TrackingStatus.TRACKING and pos[-1] <= 5.0
    assert state.recoveries >= 1


def test_kidnapped_camera_is_found_again_within_30_frames(tracker: ModelTracker) -> None:
    flight = object_flight(50, seed=4)
    moved = kidnap(flight, 15, [0.06, -0.05, 0.06], np.radians(10.0) * np.array([0.6, 0.0, -0.8]))
    images = list(render_camera_flight(tabletop_scene(), moved, tracker.camera, rng=np.random.default_rng(4)))
    start = flight.pose(0)
    pos, rot, _, _ = _run(tracker, moved, images, tracker.start(start), 4)
    limit_mm, limit_deg = 2.0 * np.median(pos[:15]), 2.0 * np.median(rot[:15])
    back = np.flatnonzero((pos[15:] <= max(limit_mm, 1.0)) & (rot[15:] <= max(limit_deg, 0.1)))
    assert back.size and back[0] <= 30


def test_motion_model_carries_the_cloud_at_its_velocity(tracker: ModelTracker) -> None:
    quiet = ModelTracker(
        tracker.scene, tracker.camera, TrackerSettings(velocity_noise_m_s=1e-12, angular_noise_rad_s=1e-12)
    )
    flight = object_flight(2, seed=0)
    state = quiet.start(flight.pose(0))
    state = replace(
        state, velocity_m_s=np.array([0.3, 0.0, -0.1]), angular_rate_rad_s=np.array([0.0, 0.0, 0.6])
    )
    moved = quiet.predict(state, 0.1, np.random.default_rng(0))
    assert np.allclose(moved.positions_m - state.positions_m, [0.03, 0.0, -0.01], atol=1e-9)
    assert np.allclose(rotation_angle_rad(moved.rotations, state.rotations), 0.06, atol=1e-9)


def test_match_fraction_is_high_at_the_truth_and_low_without_the_part(tracker: ModelTracker) -> None:
    flight = object_flight(2, seed=2)
    p, R = flight.p_world_camera_m[0], flight.R_world_camera[0]
    truth = CameraPose(p, R)
    with_part = render_view(tabletop_scene(), R, p, tracker.camera)
    without = render_view(tabletop_scene(with_part=False), R, p, tracker.camera)
    pose = (truth.R_camera_world, truth.t_camera_world_m)
    high, n = match_fraction(EdgeFit(tracker.samples, tracker.camera, tracker.edges(with_part)), *pose)
    low, _ = match_fraction(EdgeFit(tracker.samples, tracker.camera, tracker.edges(without)), *pose)
    assert n > 100 and high >= 0.6 and low <= 0.25


def test_offsets_reach_the_step_not_the_pixel_canny_marks() -> None:
    # regression (edge bias): Canny marks the pixel before an axis-aligned step (column 11 for a step between
    # columns 11 and 12, at 11.5, either polarity); the offsets go to the step itself, from either side
    for polarity in (1, -1):
        image = np.full((24, 24), 100 - 60 * polarity, dtype=np.uint8)
        image[:, 12:] = 100 + 60 * polarity
        edges = extract_image_edges(image, with_gradients=True)
        assert set(np.nonzero(edges.edge_map)[1].tolist()) == {12 - 1}
        u = np.array([11.5, 10.0, 13.2, 11.5])
        normal_u = np.array([1.0, 1.0, 1.0, -1.0])
        d = oriented_offsets(u, np.full(4, 12.0), normal_u, np.zeros(4), edges, 4, 0.9)
        assert np.allclose(d, [0.0, 1.5, -1.7, 0.0], atol=0.05)


@pytest.mark.parametrize("seed", [0, 2])
def test_kidnap_search_is_not_won_by_slivers_of_the_model(tracker: ModelTracker, seed: int) -> None:
    # regression: paper B's scorings are fractions of the points shown, so a wide recovery search settled on
    # poses that showed a sliver of the part (90 of 500 points); with the bench's kidnaps of these seeds
    # (0.1 m / 10 deg at frame 75 of 150) the tracker never came back
    flight = object_flight(150, seed=seed)
    part = bench_kidnap(flight, 75, seed).part(68, 100)
    images = list(
        render_camera_flight(tabletop_scene(), part, tracker.camera, rng=np.random.default_rng(seed))
    )
    start = part.pose(0)
    pos, rot, status, _ = _run(tracker, part, images, tracker.start(start), seed)
    assert status[6] is TrackingStatus.TRACKING and status[7] is not TrackingStatus.TRACKING  # kidnap seen
    back = np.flatnonzero((pos[7:] <= 5.0) & (rot[7:] <= 0.5))
    assert back.size and back[0] <= 20


def test_skipped_frames_widen_the_prediction_and_tracking_holds(tracker: ModelTracker) -> None:
    # latest-wins under load: runs of 1-3 frames dropped; the stamps say how much time passed
    flight, images = rendered_object_flight(60, 5, tracker.camera)
    kept = [i for i in range(60) if i < 10 or i % 7 not in (1, 2, 3) or i % 14 == 1]
    part = CameraFlight(flight.times_s[kept], flight.p_world_camera_m[kept], flight.R_world_camera[kept])
    states = list(
        track_model(tracker, [images[i] for i in kept], part.times_s, tracker.start(flight.pose(0)),
                    np.random.default_rng(5))
    )  # fmt: skip
    pos, rot = pose_errors_mm_deg(states, part.p_world_camera_m, part.R_world_camera)
    gaps = np.diff(part.times_s) / np.diff(flight.times_s[:2])[0]
    assert gaps.max() >= 3.0  # the test skips frames
    assert np.max(pos) <= 10.0 and np.median(pos) <= 3.0 and np.max(rot) <= 1.0
    assert all(s.status is TrackingStatus.TRACKING for s in states)
    # the noise state counted the gaps without taking them for the frame interval
    noise = states[-1].process_noise
    assert noise is not None and np.isclose(noise.frame_interval_s or 0.0, 1.0 / 30.0, rtol=0.05)


def test_a_frame_matching_well_short_of_the_expected_match_is_not_trusted(tracker: ModelTracker) -> None:
    flight, images = rendered_object_flight(8, 6, tracker.camera)
    states = list(
        track_model(
            tracker, images[:7], flight.times_s[:7], tracker.start(flight.pose(0)), np.random.default_rng(6)
        )
    )
    state = states[-1]
    assert state.status is TrackingStatus.TRACKING and 0.0 < state.expected_match <= 1.0
    dt = float(flight.times_s[7] - flight.times_s[6])
    edges = tracker.edges(images[7])
    as_expected = tracker.step(state, edges, dt, np.random.default_rng(7))
    assert as_expected.status is TrackingStatus.TRACKING
    assert as_expected.match >= tracker.config.lost_match  # the absolute test alone would pass it
    # the same frame and pose, where this model used to match far better: not trusted
    spoilt = replace(state, expected_match=as_expected.match / (0.9 * tracker.config.trust_ratio))
    doubted = tracker.step(spoilt, edges, dt, np.random.default_rng(7))
    assert doubted.status is TrackingStatus.SEARCHING and doubted.search_pending


def test_first_search_does_not_take_clutter_for_a_hidden_part(tracker: ModelTracker) -> None:
    # regression (issue 25, small/5/slow seed 2: the camera behind the scene's back wall from frame 0): with
    # no trusted frame yet the search had nothing to compare with, read `tracking` on a fit to clutter (41 %
    # of 87 points shown here, frame 3), and that pose became the reference of the relative trust test
    flight = object_flight(5, seed=0)
    clutter = tabletop_scene(with_part=False)
    images = list(render_camera_flight(clutter, flight, tracker.camera, rng=np.random.default_rng(0)))
    _, _, status, state = _run(tracker, flight, images, tracker.start(flight.pose(0)), 0)
    assert TrackingStatus.TRACKING not in status, "a fit to clutter was taken for the hidden part"
    assert state.expected_match == 0.0 and state.bad_frames == len(images)
