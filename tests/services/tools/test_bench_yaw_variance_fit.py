"""``bench consistency --fit-yaw``: the terms of a measured yaw pair's variance read per pair, and the fit."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from common.provenance import Provenance
from common.sim.field import field_flight
from common.yaw import YawSettings, honest
from services.tools.bench.yaw_field import run_core
from services.tools.bench.yaw_variance_fit import pair_terms
from services.tools.cli import main

pytestmark = [pytest.mark.slow]


def test_the_terms_read_per_pair_rebuild_the_published_variance() -> None:
    """With the constants in use, ``terms @ coefficients`` is each measured pair's published variance: the
    five runs isolate the terms (and the constants are restored after them)."""
    errors, terms, names = pair_terms(seed=5, frames=60, scenarios=["low_altitude"])
    flight = field_flight("low_altitude", seed=5, n_frames=60)
    published = []
    for gyro in (True, False):
        series = run_core(flight, YawSettings(), None, gyro)
        measured = np.array([p is Provenance.MEASURED for p in series.provenance])
        published.append(np.asarray(series.delta_variance_rad2)[measured])
    in_use = np.array(
        [
            honest.RESIDUAL_SHARE,
            honest.WARPED_FLOOR_DEG**2,
            honest.SHIFT_SHARE**2,
            honest.AMBIGUITY_DEG**2,
            honest.UNREFINED_PULL**2,
        ]
    )
    assert terms.shape == (errors.size, 5) and set(names) == {"low_altitude"} and errors.size >= 40
    assert terms @ in_use == pytest.approx(np.concatenate(published), rel=1e-9)
    # the floor's and the ambiguity's terms (per deg^2): at most (1 deg)^2 per patch of the 40, the floor's 0
    # on a pair measured on frame k as it is
    assert np.all(terms[:, 1:] >= 0.0) and np.all(terms[:, [1, 3]] <= math.radians(1.0) ** 2 * 40)
    assert np.all(terms[:, 3] > 0.0)  # every pair's patches have a finite peak ratio
    # the pull's term: only on pairs measured on the raw frames (no warp, so no floor)
    unrefined = terms[:, 4] > 0.0
    assert unrefined.any() and not np.any(unrefined & (terms[:, 1] > 0.0))


def test_the_fit_writes_its_constants_and_a_two_fold_check(tmp_path: Path) -> None:
    code = main([
        "bench", "--out", str(tmp_path), "consistency", "--fit-yaw", "--seeds", "4", "--field-frames", "20",
        "--scenarios", "checkerboard", "field",
    ])  # fmt: skip
    assert code in (0, None)
    result = json.loads((tmp_path / "consistency.json").read_text())
    assert result["seeds"] == [0, 1] and len(result["two_fold"]) == 2
    assert set(result["fitted"]) == {
        "RESIDUAL_SHARE", "WARPED_FLOOR_DEG", "SHIFT_SHARE", "AMBIGUITY_DEG", "UNREFINED_PULL"
    }  # fmt: skip
    assert all(v >= 0 for v in result["fitted"].values()) and max(result["fitted"].values()) > 0
    # maximum likelihood scales the model until its own samples' mean NEES is 1
    assert result["fitted_score"]["mean_nees"] == pytest.approx(1.0, abs=0.02)
    # 20 frames turn more than refine_min_deg at every pair: the pull's term, which no pair exercised,
    # cannot be fitted and keeps its value (the fit once stopped on it)
    assert result["unexercised_terms"] == [4]
    assert result["fitted"]["UNREFINED_PULL"] == result["in_use"]["UNREFINED_PULL"] == honest.UNREFINED_PULL
    assert result["in_use"]["SHIFT_SHARE"] == honest.SHIFT_SHARE
    assert result["in_use"]["AMBIGUITY_DEG"] == honest.AMBIGUITY_DEG
