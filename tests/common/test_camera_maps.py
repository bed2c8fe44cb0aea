"""``common.camera_maps``: the lens maps the simulator renders through are made once per lens."""

from __future__ import annotations

import numpy as np
import pytest

from common.camera import CameraModel, Distortion, DistortionModel
from common.camera_maps import _pixel_maps, through_lens_maps


def _lens(k1: float) -> CameraModel:
    return CameraModel(
        width=96, height=64, fx=80.0, fy=80.0, cx=47.5, cy=31.5,
        distortion=Distortion(DistortionModel.RADTAN, (k1, 0.0, 0.0, 0.0, 0.0)),
    )  # fmt: skip


def test_through_lens_maps_are_made_once_per_lens_and_cannot_be_changed_by_a_caller() -> None:
    maps = through_lens_maps(_lens(-0.1))
    # an equal camera (another object) reads the same maps; another lens gets its own
    assert through_lens_maps(_lens(-0.1)) is maps
    other = through_lens_maps(_lens(-0.2))
    assert other is not maps and not np.array_equal(other[0], maps[0])
    # the memo holds what the maps are: equal to maps made afresh
    fresh = _pixel_maps(_lens(-0.1), _lens(-0.1).undistort_px)
    assert all(np.array_equal(a, b) for a, b in zip(maps, fresh, strict=True))
    with pytest.raises(ValueError, match="read-only"):
        maps[0][0, 0] = 0.0
