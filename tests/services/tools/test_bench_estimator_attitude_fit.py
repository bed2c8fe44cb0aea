"""``bench consistency --fit-attitude``: the terms of an attitude's published tilt and yaw variances read per
message, and the fit of the tilt scale and the yaw's floor and drift."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from services.estimator.outputs import PublishedUncertainty
from services.estimator.settings import EstimatorSettings
from services.tools.bench.consistency_runs import (
    FLIGHTS,
    attitude_errors,
    estimator_outputs,
    published_messages,
)
from services.tools.bench.estimator_attitude_fit import FLOOR_UNIT_RAD2, flight_terms
from services.tools.cli import main

pytestmark = [pytest.mark.slow]


def test_the_terms_read_per_attitude_rebuild_the_published_tilt_and_yaw_variances() -> None:
    """With the constants in use, the terms give each published attitude's tilt and yaw variances: the two
    publications isolate the angle turned's term, and the errors are the published attitudes'."""
    flight = FLIGHTS["paper_c"](2)
    produced = estimator_outputs(flight, 300)
    read = flight_terms(flight, produced)
    model = PublishedUncertainty()
    angles, P = attitude_errors(flight, published_messages(produced, EstimatorSettings().max_pair_s, model))
    n = angles.shape[0]
    assert n >= 100 and read["tilt_terms"].shape == (2 * n, 1) and read["yaw_terms"].shape == (n, 2)
    tilt = model.tilt_variance_scale * read["tilt_terms"][:, 0]
    assert tilt == pytest.approx(np.concatenate([P[:, 0, 0], P[:, 1, 1]]), rel=1e-9)
    in_use = np.array([model.yaw_drift_per_rad**2, model.yaw_floor_rad2 / FLOOR_UNIT_RAD2])
    assert read["yaw_offset"] + read["yaw_terms"] @ in_use == pytest.approx(P[:, 2, 2], rel=1e-9)
    assert np.all(np.diff(read["yaw_terms"][:, 0]) >= 0.0) and read["yaw_terms"][-1, 0] > 0.0  # turned
    assert read["yaw_errors"] == pytest.approx(angles[:, 2])


def test_the_attitude_fit_writes_its_constants_and_a_two_fold_check(tmp_path: Path) -> None:
    code = main([
        "bench", "--out", str(tmp_path), "consistency", "--fit-attitude", "--seeds", "4",
        "--estimator-frames", "120",
    ])  # fmt: skip
    assert code in (0, None)
    result = json.loads((tmp_path / "consistency.json").read_text())
    assert result["seeds"] == [0, 1] and len(result["two_fold"]) == 2
    assert result["yaw_fitted_on"] in FLIGHTS
    assert result["fitted"]["tilt_variance_scale"] > 0.0
    assert result["in_use"]["tilt_variance_scale"] == pytest.approx(
        PublishedUncertainty().tilt_variance_scale
    )
    # one term for both flights' tilt: maximum likelihood scales it to a mean NEES of 1 per axis over them
    tilt = [result["fitted_score"]["tilt"][name]["mean_nees"] for name in FLIGHTS]
    assert min(tilt) <= 1.0 <= max(tilt)
    # the yaw constants are the flight's that needs the larger variance: no flight is overconfident beyond
    # what its own fit would give (its own fit's mean NEES is about 1 or below)
    assert all(result["fitted_score"]["yaw"][name]["mean_nees"] < 1.2 for name in FLIGHTS)
