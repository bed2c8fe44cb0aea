from __future__ import annotations

import math

import numpy as np

from common.yaw import YawSettings, estimate_pair, make_patch_grid
from common.yaw.reference import reference_pair, reference_settings, reference_yaw_series

from .conftest import PairMaker


def test_reference_and_core_agree_on_a_small_rotation(nadir_pair: PairMaker) -> None:
    a, b = nadir_pair(1.5, (4.0, -3.0))
    settings = reference_settings()
    reference = reference_pair(a, b, make_patch_grid(a.shape, settings), settings)
    assert reference.fit.ok
    core = estimate_pair(a, b, YawSettings())
    assert abs(math.degrees(reference.delta_yaw_rad) - 1.5) < 0.1
    assert abs(math.degrees(reference.delta_yaw_rad - core.delta_yaw_rad)) < 0.1


def test_reference_yaw_series_integrates(nadir_pair: PairMaker) -> None:
    a, b = nadir_pair(0.8)
    _, c = nadir_pair(1.6)
    yaw = reference_yaw_series([a, b, c])
    assert yaw[0] == 0.0
    assert np.allclose(np.degrees(yaw), [0.0, 0.8, 1.6], atol=0.1)
