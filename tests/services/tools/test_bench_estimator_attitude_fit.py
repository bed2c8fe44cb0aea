"""``bench consistency --fit-attitude``: the terms of an attitude's published tilt and yaw variances read per
message, and the fit of the tilt scale and the yaw's floor, drift and over-read scale."""

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
    """With the constants in use, the terms give each published attitude's tilt and yaw variances: the three
    publications isolate the angle turned's and the over-read turn's terms, and the errors are the published
    attitudes'."""
    flight = FLIGHTS["paper_c"](2)
    produced = estimator_outputs(flight, 300)
    read = flight_terms(flight, produced)
    model = PublishedUncertainty()
    angles, P = attitude_errors(flight, published_messages(produced, EstimatorSettings().max_pair_s, model))
    n = angles.shape[0]
    assert n >= 100 and read["tilt_terms"].shape == (2 * n, 1) and read["yaw_terms"].shape == (n, 3)
    tilt = model.tilt_variance_scale * read["tilt_terms"][:, 0]
    assert tilt == pytest.approx(np.concatenate([P[:, 0, 0], P[:, 1, 1]]), rel=1e-9)
    in_use = np.array(
        [model.yaw.drift_per_rad**2, model.yaw.floor_rad2 / FLOOR_UNIT_RAD2, model.yaw.over_read_scale**2]
    )
    assert read["yaw_offset"] + read["yaw_terms"] @ in_use == pytest.approx(P[:, 2, 2], rel=1e-9)
    for column in (0, 2):  # the angle turned and the part of it over-read only grow
        steps = np.diff(read["yaw_terms"][:, column])
        assert np.all(steps >= -1e-15) and read["yaw_terms"][-1, column] > 0.0  # (float rounding of P)
    assert np.all(read["yaw_terms"][:, 2] < read["yaw_terms"][:, 0] + 1e-18)  # over-read < turned
    assert read["yaw_errors"] == pytest.approx(angles[:, 2])


def test_the_attitude_fit_writes_its_constants_and_a_two_fold_check(tmp_path: Path) -> None:
    code = main([
        "bench", "--out", str(tmp_path), "consistency", "--fit-attitude", "--seeds", "4",
        "--estimator-frames", "120",
    ])  # fmt: skip
    assert code in (0, None)
    result = json.loads((tmp_path / "consistency.json").read_text())
    assert result["seeds"] == [0, 1] and len(result["two_fold"]) == 2
    assert result["cautious_yaw_flight"] in FLIGHTS
    assert set(result["fitted"]) == {"tilt_variance_scale", "yaw_drift_per_rad", "yaw_floor_rad2",
                                     "yaw_over_read_scale"}  # fmt: skip
    assert result["fitted"]["tilt_variance_scale"] > 0.0
    assert result["in_use"]["tilt_variance_scale"] == pytest.approx(
        PublishedUncertainty().tilt_variance_scale
    )
    # one term for both flights' tilt: maximum likelihood scales it to a mean NEES of 1 per axis over them
    tilt = [result["fitted_score"]["tilt"][name]["mean_nees"] for name in FLIGHTS]
    assert min(tilt) <= 1.0 <= max(tilt)
    # one yaw model for both flights, fitted by maximum likelihood beside the filter's own yaw variance (which
    # it cannot lower): neither flight is published overconfident, nor with the per-flight (cautious) fit
    for score in ("fitted_score", "cautious_yaw_score"):
        nees = {name: result[score]["yaw"][name]["mean_nees"] for name in FLIGHTS}
        assert all(value < 1.2 for value in nees.values()), (score, nees)
