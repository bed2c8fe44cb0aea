"""The cost-of-security comparison: secure minus open, paired per repeat and per frame."""

from __future__ import annotations

import numpy as np
import pytest

from services.tools.bench.security import OVERHEAD_WARMUP, paired_differences


def run(ms: list[float], yaw_offset: float = 0.0) -> dict[int, tuple[float, float]]:
    return {s: (t, 0.01 * s + yaw_offset) for s, t in enumerate(ms)}


def test_paired_differences_are_taken_frame_by_frame_within_each_repeat_after_the_warm_up() -> None:
    rng = np.random.default_rng(3)
    frames = OVERHEAD_WARMUP + 40
    open_runs, secure_runs = [], []
    for repeat in range(5):
        base = 5.0 + 3.0 * repeat + rng.normal(0.0, 0.2, frames)  # the host's load drifts between repeats
        base[: OVERHEAD_WARMUP + 1] = 1000.0  # warm-up frames are left out
        open_runs.append(run(list(base)))
        secure = base + 0.5
        secure[: OVERHEAD_WARMUP + 1] = 0.0
        secure_runs.append(run(list(secure)))
    result = paired_differences(open_runs, secure_runs)
    assert result["secure_minus_open_per_repeat"]["n"] == 5
    assert result["secure_minus_open_per_repeat"]["median_ms"] == pytest.approx(0.5)
    assert result["secure_minus_open_per_frame"]["n"] == 5 * (frames - OVERHEAD_WARMUP - 1)
    assert result["secure_minus_open_per_frame"]["p95_ms"] == pytest.approx(0.5)
    assert result["max_yaw_difference_rad"] == 0.0


def test_a_lost_frame_is_left_out_of_the_pairs_and_a_yaw_difference_is_reported() -> None:
    frames = OVERHEAD_WARMUP + 10
    a = run([2.0] * frames)
    b = run([3.0] * frames, yaw_offset=1e-3)
    del b[frames - 1]
    result = paired_differences([a], [b])
    assert result["secure_minus_open_per_frame"]["n"] == frames - OVERHEAD_WARMUP - 2
    assert result["max_yaw_difference_rad"] == pytest.approx(1e-3)
    assert paired_differences([], [])["secure_minus_open_per_repeat"] == {"n": 0}
