from __future__ import annotations

import pytest

from common.metrics import yaw_error_stats
from common.sim.flight import hover_flight
from common.yaw import YawSettings
from services.tools.demo_yaw import track_frames


@pytest.mark.slow
def test_full_simulated_hover_meets_the_accuracy_targets() -> None:
    """Paper A's 2041-frame hover: max accumulated mean error (eq. 8, N = 100) <= 1 deg, final <= 2 deg."""
    flight = hover_flight(seed=0)
    assert flight.n_frames == 2041
    run = track_frames(flight.frames(), YawSettings())
    stats = yaw_error_stats(run.yaw_rad + flight.yaw_rad[0], flight.yaw_rad, ame_window=100)
    assert stats.max_ame_deg <= 1.0
    assert abs(stats.final_deg) <= 2.0
    assert not run.low_confidence.any()
