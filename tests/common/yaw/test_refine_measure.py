"""The refinement measured elsewhere (:data:`common.yaw.stages.RefineMeasure`): a master hands a turning
pair's second pass to its members. Measured from the crops alone (:func:`common.yaw.patchwork.measure_crops`,
what a member computes), the pair equals the in-process tracker's bit for bit; a hook that answers nothing
usable leaves the first pass's trusted fit."""

from __future__ import annotations

import numpy as np
import pytest

from common.yaw import YawSettings, YawTracker, for_frame
from common.yaw.correlation import measure_patches, patch_spectra
from common.yaw.grid import IntArray, U8Array, make_patch_grid
from common.yaw.measurement import PatchMeasurement
from common.yaw.patchwork import PatchWorkError, measure_crops
from common.yaw.stages import EstimateMethod, refine_indices

from .conftest import PairMaker


def _first_pass(tracker: YawTracker, a: U8Array, b: U8Array) -> PatchMeasurement:
    """The frame's first pass as a master gathers it from its members (no spectra cached)."""
    grid, settings = tracker.grid, tracker.settings
    return measure_patches(
        patch_spectra(a, grid, None, settings), patch_spectra(b, grid, None, settings), settings
    )


@pytest.mark.parametrize("grid", [(8, 5), (16, 12)])
@pytest.mark.parametrize("delta_deg", [0.6, -2.5])
def test_the_refinement_measured_from_crops_equals_the_in_process_pair(
    nadir_pair: PairMaker, grid: tuple[int, int], delta_deg: float
) -> None:
    a, b = nadir_pair(delta_deg)
    settings = YawSettings(grid_cols=grid[0], grid_rows=grid[1])
    settings = for_frame(settings, a.shape)
    tracker = YawTracker(settings, make_patch_grid(a.shape, settings))
    _, local = tracker.track(tracker.initial_state(a), b)
    assert local.method is EstimateMethod.REFINED
    asked: list[IntArray] = []
    previous_level = tracker.grid.level_image(a)

    def on_members(indices: IntArray, crops_u8: U8Array) -> PatchMeasurement:
        asked.append(indices)
        return measure_crops(settings, indices, crops_u8, tracker.grid.crop_level(previous_level, indices))

    state = tracker.initial_state(a, with_spectra=False)
    _, remote = tracker.conclude(state, b, _first_pass(tracker, a, b), refine_measure=on_members)
    assert len(asked) == 1 and np.array_equal(asked[0], refine_indices(settings))
    assert remote.method is EstimateMethod.REFINED
    assert remote.delta_yaw_rad == local.delta_yaw_rad  # bit for bit
    assert remote.delta_variance_rad2 == local.delta_variance_rad2
    assert remote.inlier_count == local.inlier_count == remote.patch_count


def test_a_refinement_that_measured_nothing_keeps_the_first_pass(nadir_pair: PairMaker) -> None:
    a, b = nadir_pair(2.0)
    tracker = YawTracker(YawSettings(), make_patch_grid(a.shape, YawSettings()))

    def nothing(indices: IntArray, crops_u8: U8Array) -> PatchMeasurement:
        n = indices.size
        return PatchMeasurement(indices, np.zeros((n, 2)), np.zeros(n), np.zeros(n), np.zeros(n, bool))

    state = tracker.initial_state(a, with_spectra=False)
    _, estimate = tracker.conclude(state, b, _first_pass(tracker, a, b), refine_measure=nothing)
    assert estimate.method is EstimateMethod.PATCHES and not estimate.low_confidence
    assert abs(np.degrees(estimate.delta_yaw_rad) - 2.0) < 0.2


def test_crops_that_do_not_match_their_indices_are_refused() -> None:
    settings = YawSettings()
    crops = np.zeros((3, 32, 32), np.uint8)
    with pytest.raises(PatchWorkError, match="differ"):
        measure_crops(settings, np.arange(3), crops, crops[:2])
    with pytest.raises(PatchWorkError, match="differ"):
        measure_crops(settings, np.arange(4), crops, crops)
