"""A pose the model tracker does not trust (``searching`` / ``lost``) carries a covariance that says so (never
a tracked frame's), and every recovery search starts from the last trusted pose."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.localization.pose import CameraPose, perturb
from common.localization.search import untrusted_covariance
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings, TrackerState, TrackingStatus
from common.localization.tracking import track_model
from common.sim.objects import object_camera, object_flight, tabletop_model, tabletop_scene
from common.sim.scene import render_view

finite = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(finite, min_size=6, max_size=6),
    st.lists(finite, min_size=36, max_size=36),
    st.floats(1e-4, 1.0),
    st.floats(1e-4, 1.0),
)
def test_untrusted_covariance_spans_the_box_the_cloud_and_the_last_good_pose(
    offset: list[float], cloud_entries: list[float], spread_m: float, spread_rad: float
) -> None:
    A = np.reshape(cloud_entries, (6, 6))
    cloud = 1e-3 * A @ A.T
    last = CameraPose(np.array([0.1, -0.2, 0.3]), np.eye(3))
    pose = CameraPose(
        last.p_world_camera_m + np.asarray(offset[:3]),
        perturb(np.eye(3)[None], 0.5 * np.asarray(offset[3:])[None])[0],
    )
    cov = untrusted_covariance(cloud, pose, last, (spread_m, spread_rad))
    box = np.diag(np.repeat(np.square([spread_m, spread_rad]) / 3.0, 3))
    assert np.allclose(cov, cov.T)
    # never tighter than the cloud, nor than the search box
    assert np.linalg.eigvalsh(cov - cloud).min() >= -1e-9
    assert np.linalg.eigvalsh(cov - box).min() >= -1e-9
    # the last trusted pose lies within one sigma of the guess
    e = np.concatenate([last.p_world_camera_m - pose.p_world_camera_m, -0.5 * np.asarray(offset[3:])])
    assert float(e @ np.linalg.solve(cov, e)) <= 1.0 + 1e-6


@pytest.fixture(scope="module")
def object_gone() -> tuple[ModelTracker, list[TrackerState], np.ndarray]:
    """Tracked for 12 frames, then 14 frames of the scene without the part (nothing to track), then back."""
    tracker = ModelTracker(tabletop_model(), object_camera(), TrackerSettings())
    flight = object_flight(30, seed=1)
    world, clutter = tabletop_scene(), tabletop_scene(with_part=False)
    rng = np.random.default_rng(1)
    images = [
        render_view(clutter if 12 <= i < 26 else world, R, p, tracker.camera, rng=rng)
        for i, (p, R) in enumerate(zip(flight.p_world_camera_m, flight.R_world_camera, strict=True))
    ]
    start = tracker.start(flight.pose(0))
    states = list(track_model(tracker, images, flight.times_s, start, np.random.default_rng(2)))
    return tracker, states, flight.p_world_camera_m


def test_an_untrusted_pose_is_published_with_the_search_s_uncertainty(
    object_gone: tuple[ModelTracker, list[TrackerState], np.ndarray],
) -> None:
    tracker, states, truth_m = object_gone
    assert states[11].status is TrackingStatus.TRACKING
    tracked_sigma_m = np.sqrt(np.diag(states[11].covariance)[:3])
    untrusted = [(i, s) for i, s in enumerate(states) if s.status is not TrackingStatus.TRACKING]
    assert len(untrusted) >= 10
    for i, s in untrusted:
        sigma_m = np.sqrt(np.diag(s.covariance)[:3])
        box_m = tracker.position_spread_m(s.distance_m) * s.spread_factor
        # the first bad frame too (its cloud is still the tight tracking one)
        assert np.all(sigma_m >= box_m / np.sqrt(3.0) - 1e-12), i
        assert np.all(sigma_m >= 10.0 * tracked_sigma_m), i
        assert np.all(np.linalg.eigvalsh(s.covariance) >= 0.0)
        # the truth lies within the stated uncertainty (3-dof position, chi-square 99.9 %: 16.3)
        e = s.pose.p_world_camera_m - truth_m[i]
        assert float(e @ np.linalg.solve(s.covariance[:3, :3], e)) <= 16.3, i


def test_every_recovery_search_starts_from_the_last_trusted_pose(
    object_gone: tuple[ModelTracker, list[TrackerState], np.ndarray],
) -> None:
    """Half the candidates about the last trusted pose, half about it carried by its last trusted motion
    (never about the drifting guesses of the bad frames)."""
    tracker, states, _ = object_gone
    trusted = states[11]
    edges = tracker.edges(np.zeros((tracker.camera.height, tracker.camera.width), dtype=np.uint8))
    interval = trusted.process_noise.frame_interval_s if trusted.process_noise else None
    assert interval is not None
    for s in states[12:26]:
        assert s.status is not TrackingStatus.TRACKING and s.search_pending
        assert np.array_equal(s.last_good.p_world_camera_m, trusted.pose.p_world_camera_m)
        assert np.array_equal(s.velocity_m_s, trusted.velocity_m_s)  # the last trusted motion is kept
        spread_m = tracker.position_spread_m(s.distance_m) * s.spread_factor
        base_m = spread_m / s.spread_factor
        _, positions, _ = tracker._search_candidates(s, edges, base_m, np.random.default_rng(0), interval)
        half = len(positions) // 2
        assert np.abs(positions[-half:] - trusted.pose.p_world_camera_m).max() <= spread_m + 1e-12
        elapsed = min(s.since_good_s + interval, tracker.config.noise.max_gap_frames * interval)
        carried_m = trusted.pose.p_world_camera_m + trusted.velocity_m_s * elapsed
        assert np.abs(positions[:-half] - carried_m).max() <= spread_m + 1e-12
    assert states[-1].status is TrackingStatus.TRACKING  # and it recovered
