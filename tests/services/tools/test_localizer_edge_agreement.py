"""Regression (issue 26's localizer line): the office frames the tracker refines off their true pose are
published with the uncertainty they have (:func:`common.localization.refine.edge_agreement`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.consistency import normalised_errors_squared
from common.localization.tracker_state import TrackerSettings, TrackingStatus
from services.tools.bench.consistency_runs import tracked_scene
from services.tools.bench.localizer_field import _office_scene

pytestmark = [pytest.mark.slow]

#: the published covariance before the edge agreement: the fused one's diagonal times 0.32
BEFORE = replace(TrackerSettings(), covariance_shrinkage=1.0, covariance_scale=0.32, agreement_power=0.0)


def _nees(settings: TrackerSettings) -> dict[str, np.ndarray]:
    states, error = tracked_scene(_office_scene(122, 0), 0, settings)
    out = {}
    for name, frames in (("locked", range(106, 121)), ("before", range(30, 61))):
        kept = [i for i in frames if states[i].status is TrackingStatus.TRACKING]
        assert len(kept) >= 0.8 * len(frames)
        out[name] = normalised_errors_squared(error[kept], [states[i].covariance for i in kept])
        out[f"{name} agreement"] = np.array([states[i].edge_agreement for i in kept])
    return out


def test_office_frames_locked_off_their_pose_are_no_longer_published_within_a_centimetre_regression() -> None:
    """Regression (issue 26's localizer line): in the office flight (seed 0; every seed does it) frames
    106-120 refine 20-70 mm off along the direction few edges hold, and the published covariance (the fused
    one's diagonal times 0.32) claimed about 1 cm: their median 6-dof NEES was above chi-square's 99 %
    (16.8). With the edge agreement (3 times and more that of frames 30-60, before the bench's kidnap) the
    median there is below it, as it is for frames 30-60."""
    now, before = _nees(TrackerSettings()), _nees(BEFORE)
    assert np.median(now["locked agreement"]) > 3.0 * np.median(now["before agreement"]), now
    assert np.median(before["locked"]) > 16.8, before  # what the regression was
    assert np.median(now["locked"]) < 16.8 and np.median(now["before"]) < 16.8, now
