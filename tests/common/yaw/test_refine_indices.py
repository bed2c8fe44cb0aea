"""The refinement's sub-grid (:func:`common.yaw.stages.refine_indices`): a large grid refines a spread subset.

Regression: on a 16x12 grid at 1080p, a frame turning more than ``refine_min_deg`` measured all 192 patches
a second time (131 ms in-process on top of 116), and on the distributed path the master paid that alone.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.yaw import YawSettings, YawTracker
from common.yaw.grid import make_patch_grid
from common.yaw.stages import EstimateMethod, refine_indices

from .conftest import PairMaker


def _count(cols: int, rows: int, step: int) -> int:
    return -(-cols // step) * -(-rows // step)


@given(st.integers(2, 40), st.integers(2, 40), st.integers(8, 300))
def test_the_sub_grid_is_every_kth_column_and_row_with_the_smallest_k_within_the_cap(
    cols: int, rows: int, cap: int
) -> None:
    settings = YawSettings(grid_cols=cols, grid_rows=rows, refine_max_patches=cap)
    chosen = refine_indices(settings)
    assert chosen.size <= cap and chosen.size >= 1
    assert np.all(np.diff(chosen) > 0) and chosen[0] >= 0 and chosen[-1] < cols * rows
    picked_cols, picked_rows = np.unique(chosen % cols), np.unique(chosen // cols)
    assert chosen.size == picked_cols.size * picked_rows.size  # a product of columns and rows
    steps = np.concatenate([np.diff(picked_cols), np.diff(picked_rows)])
    step = int(steps[0]) if steps.size else max(cols, rows)
    assert np.all(steps == step)  # one step, in both directions
    if step > 1:
        assert _count(cols, rows, step - 1) > cap  # the smallest step within the cap
    # centred: the columns (rows) left out before the first and after the last differ by at most one
    assert abs(int(picked_cols[0]) - (cols - 1 - int(picked_cols[-1]))) <= 1
    assert abs(int(picked_rows[0]) - (rows - 1 - int(picked_rows[-1]))) <= 1


def test_the_default_grid_refines_every_patch() -> None:
    settings = YawSettings()
    assert np.array_equal(refine_indices(settings), np.arange(settings.grid_cols * settings.grid_rows))


@pytest.mark.parametrize("delta_deg", [1.0, -2.0, 3.0])
def test_a_large_grid_refines_a_sub_grid_as_accurately_as_every_patch(
    nadir_pair: PairMaker, delta_deg: float
) -> None:
    a, b = nadir_pair(delta_deg)
    results = {}
    for cap in (48, 4096):
        settings = YawSettings(grid_cols=16, grid_rows=12, refine_max_patches=cap)
        tracker = YawTracker(settings, make_patch_grid(a.shape, settings))
        _, estimate = tracker.track(tracker.initial_state(a), b)
        assert estimate.method is EstimateMethod.REFINED
        results[cap] = estimate
    assert results[48].patch_count == 48 and results[4096].patch_count == 192
    for estimate in results.values():
        assert abs(abs(math.degrees(estimate.delta_yaw_rad)) - abs(delta_deg)) < 0.01
    between = math.degrees(results[48].delta_yaw_rad - results[4096].delta_yaw_rad)
    assert abs(between) < 0.005
