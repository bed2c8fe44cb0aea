from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from common.errors import InputError
from common.metrics import accumulated_mean_error, yaw_error_rad, yaw_error_stats


def _eq8_loop(error: np.ndarray, n: int) -> np.ndarray:
    """Paper A eq. 8 written out literally (1-based k = 1..M-N, i = k..k+N)."""
    m = error.size
    out = []
    for k in range(1, m - n + 1):
        out.append(sum(abs(error[i - 1] - error[k - 1]) for i in range(k, k + n + 1)) / n)
    return np.array(out)


@settings(max_examples=30, deadline=None)
@given(
    error=arrays(np.float64, st.integers(12, 60), elements=st.floats(-5, 5)),
    window=st.integers(1, 10),
)
def test_accumulated_mean_error_is_eq8(error: np.ndarray, window: int) -> None:
    assert np.allclose(accumulated_mean_error(error, window), _eq8_loop(error, window))


def test_accumulated_mean_error_ignores_a_constant_offset_and_sees_a_step() -> None:
    assert np.all(accumulated_mean_error(np.full(300, 7.0), 100) == 0.0)
    step = np.r_[np.zeros(150), np.ones(150)]
    ame = accumulated_mean_error(step, 100)
    assert ame.shape == (200,)
    # The window starting on the last 0 sees 100 ones after it; one starting on a 1 sees none.
    assert ame.max() == pytest.approx(1.0) and ame[149] == pytest.approx(1.0)
    assert ame[0] == 0.0 and ame[150] == 0.0
    assert ame[50] == pytest.approx(0.01)


def test_yaw_error_wraps_and_stats() -> None:
    true = np.radians(np.array([179.0, -179.0, 0.0, 10.0]))
    est = np.radians(np.array([-179.0, 179.0, 1.0, 10.0]))
    assert np.allclose(np.degrees(yaw_error_rad(est, true)), [2.0, -2.0, 1.0, 0.0])
    stats = yaw_error_stats(est, true, ame_window=2)
    assert stats.frames == 4 and stats.final_deg == pytest.approx(0.0)
    assert stats.max_abs_deg == pytest.approx(2.0)
    assert stats.rms_deg == pytest.approx(math.sqrt((4 + 4 + 1) / 4))
    assert math.isnan(yaw_error_stats(est, true).max_ame_deg)  # too short for N = 100


def test_metrics_reject_bad_input() -> None:
    with pytest.raises(InputError):
        yaw_error_rad([0.0, 1.0], [0.0])
    with pytest.raises(InputError):
        yaw_error_rad([np.nan], [0.0])
    with pytest.raises(InputError):
        accumulated_mean_error(np.zeros(10), 10)
    with pytest.raises(InputError):
        accumulated_mean_error(np.zeros((3, 3)), 1)
