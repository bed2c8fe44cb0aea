from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.images import check_grey_image
from common.yaw import YawSettings, for_frame, make_patch_grid
from common.yaw.grid import level_shape, pyramid_image


def test_grid_layout_covers_the_frame_inside_its_bounds() -> None:
    settings = YawSettings(grid_cols=7, grid_rows=4, patch_size_px=32, pyramid_level=1, margin_px=10)
    grid = make_patch_grid((480, 752), settings)
    assert grid.n_patches == 28
    h, w = level_shape((480, 752), 1)
    assert (h, w) == (240, 376)
    x0, y0 = grid.origins_level_px[:, 0], grid.origins_level_px[:, 1]
    assert x0.min() >= 5 and y0.min() >= 5
    assert (x0 + 32).max() <= w - 5 and (y0 + 32).max() <= h - 5
    # Centres at full resolution, spread over the frame, symmetric about its centre.
    centres = grid.centres_px
    assert np.allclose(centres.mean(axis=0), [(752 - 2) / 2, (480 - 2) / 2], atol=1.5)
    assert np.unique(centres[:, 0]).size == 7 and np.unique(centres[:, 1]).size == 4


def test_crop_is_the_patch_slice_of_the_level_image() -> None:
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (480, 752), dtype=np.uint8)
    settings = YawSettings()
    settings = for_frame(settings, frame.shape)
    grid = make_patch_grid(frame.shape, settings)
    level = pyramid_image(frame, settings.pyramid_level)
    indices = np.array([3, 0, 17])
    crops = grid.crop(frame, indices)
    assert crops.shape == (3, settings.patch_size_px, settings.patch_size_px)
    for crop, i in zip(crops, indices, strict=True):
        rows, cols = grid.slices(int(i))
        assert np.array_equal(crop, level[rows, cols])


@pytest.mark.parametrize(
    "frame",
    [
        np.zeros((0, 0), dtype=np.uint8),
        np.zeros((480, 752), dtype=np.float32),
        np.zeros((480, 752), dtype=np.uint16),
        np.zeros((480, 752, 3), dtype=np.uint8),
        [[1, 2], [3, 4]],
    ],
    ids=["empty", "float32", "uint16", "colour", "list"],
)
def test_check_grey_image_rejects_garbage(frame: object) -> None:
    with pytest.raises(InputError):
        check_grey_image(frame)


def test_grid_rejects_small_frames_bad_indices_and_wrong_shapes() -> None:
    settings = YawSettings(pyramid_level=1)
    with pytest.raises(InputError, match="too small"):
        make_patch_grid((40, 40), settings)
    grid = make_patch_grid((480, 752), settings)
    frame = np.zeros((480, 752), dtype=np.uint8)
    with pytest.raises(InputError):
        grid.crop(frame, [grid.n_patches])
    with pytest.raises(InputError):
        grid.crop(frame, [1, 1])
    with pytest.raises(InputError, match="shape"):
        grid.crop(np.zeros((480, 750), dtype=np.uint8), [0])


def test_settings_reject_nonsense() -> None:
    with pytest.raises(InputError):
        YawSettings(patch_size_px=7)
    with pytest.raises(InputError):
        YawSettings(grid_cols=1, grid_rows=2)
    with pytest.raises(InputError):
        YawSettings(pyramid_level=-1)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 39), min_size=0, max_size=40, unique=True), st.booleans())
def test_crop_level_equals_slicing_for_any_distinct_indices(indices: list[int], ascending: bool) -> None:
    grid = make_patch_grid((480, 752), YawSettings(pyramid_level=1))
    level = np.random.default_rng(len(indices)).integers(0, 256, level_shape((480, 752), 1), dtype=np.uint8)
    idx = np.array(sorted(indices) if ascending else indices, dtype=np.int64)
    crops = grid.crop_level(level, idx)
    assert crops.shape == (len(indices), 32, 32) and crops.flags.c_contiguous and crops.flags.writeable
    for crop, i in zip(crops, idx.tolist(), strict=True):
        rows, cols = grid.slices(i)
        assert np.array_equal(crop, level[rows, cols])


@pytest.mark.parametrize("indices", [[2, 1, 1], [0, 0], [-1, 3], [5, 40], [39, 40]])
def test_check_indices_rejects_duplicates_and_out_of_range_in_any_order(indices: list[int]) -> None:
    grid = make_patch_grid((480, 752), YawSettings())
    with pytest.raises(InputError):
        grid.check_indices(np.array(indices))
