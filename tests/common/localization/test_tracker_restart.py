"""A search fixes a pose, not a motion: the motion model restarted by a search moves as the camera did since
the last good pose (when that is recent), and the image-motion ceiling is per second, not per frame."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from common.localization.process_noise import NoiseSettings, ceiling_px
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings, TrackingStatus
from common.sim.objects import object_camera, rendered_object_flight, tabletop_model


@given(st.floats(1.0, 240.0), st.floats(1.0, 240.0))
def test_the_ceiling_grows_with_the_frame_interval_beyond_the_reference_rate(
    a_hz: float, b_hz: float
) -> None:
    cfg = NoiseSettings()
    slow, fast = sorted((a_hz, b_hz))
    assert ceiling_px(cfg, 1.0 / slow) >= ceiling_px(cfg, 1.0 / fast) >= cfg.ceiling_px
    if fast >= cfg.reference_rate_hz:
        assert ceiling_px(cfg, 1.0 / fast) == cfg.ceiling_px
    else:
        assert np.isclose(ceiling_px(cfg, 1.0 / fast), cfg.ceiling_px * cfg.reference_rate_hz / fast)
    assert ceiling_px(cfg, None) == cfg.ceiling_px


def test_a_recovery_search_starts_the_motion_model_at_the_camera_s_velocity() -> None:
    tracker = ModelTracker(tabletop_model(), object_camera(), TrackerSettings())
    flight, images = rendered_object_flight(4, 2, tracker.camera)
    rng = np.random.default_rng(2)
    dt = float(flight.times_s[1] - flight.times_s[0])
    first = tracker.step(tracker.start(flight.pose(0)), tracker.edges(images[0]), 0.0, rng)
    assert first.status is TrackingStatus.TRACKING
    blank = np.zeros_like(images[1])  # the object gone for a frame: bad, a search is due
    gone = tracker.step(first, tracker.edges(blank), dt, rng)
    assert gone.status is not TrackingStatus.TRACKING and gone.search_pending
    assert np.isclose(gone.since_good_s, dt)
    found = tracker.step(gone, tracker.edges(images[2]), dt, rng)
    assert found.status is TrackingStatus.TRACKING and found.motion is not None
    true_velocity = (flight.p_world_camera_m[2] - flight.p_world_camera_m[0]) / (2.0 * dt)
    assert np.linalg.norm(true_velocity) > 0.1  # the camera moves (m/s): at rest would be far off
    assert np.linalg.norm(found.motion.velocity_m_s - true_velocity) <= 0.2 * np.linalg.norm(true_velocity)
    assert found.since_good_s == 0.0
