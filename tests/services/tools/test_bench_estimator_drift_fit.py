"""``bench consistency --fit-drift``: the terms of a pose's published horizontal variance read per pose, and
the fit of the per-pair drift and the floor."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.wire.messages import PoseEstimate
from services.estimator.outputs import MIN_VAR_XY_M2, PublishedUncertainty
from services.estimator.settings import EstimatorSettings
from services.tools.bench.consistency_runs import FLIGHTS, estimator_outputs, published_messages
from services.tools.bench.estimator_drift_fit import FLOOR_UNIT_M2, flight_terms
from services.tools.cli import main

pytestmark = [pytest.mark.slow]


def test_the_terms_read_per_pose_rebuild_the_published_horizontal_variance() -> None:
    """With the constants in use, ``terms @ coefficients`` is each tracked pose's published x (and y)
    variance: the two publications isolate the height sum's term."""
    flight = FLIGHTS["agile"](3)
    produced = estimator_outputs(flight, 160)
    read = flight_terms(flight, produced)
    messages = published_messages(produced, EstimatorSettings().max_pair_s, PublishedUncertainty())
    tracked = [m for m in messages if isinstance(m, PoseEstimate) and m.tracking_state == "tracking"]
    n = read["errors"].size // 2
    assert read["terms"].shape == (2 * n, 2) and n >= 50
    assert read["left_out"] == 0 and n == len(tracked)  # no pair failed here
    in_use = np.array([PublishedUncertainty().drift_per_pair ** 2, MIN_VAR_XY_M2 / FLOOR_UNIT_M2])
    published = np.array([m.covariance[0, 0] for m in tracked])
    assert read["terms"][:n] @ in_use == pytest.approx(published, rel=1e-9)
    assert np.all(np.diff(read["terms"][:n, 0]) > 0.0)  # the height sum grows pair by pair
    truth = flight.p_world_body_m[np.searchsorted(flight.frame_stamps_s, tracked[0].stamp_s - 1e-9)]
    assert read["errors"][0] == pytest.approx(tracked[0].p_world_body_m[0] - truth[0])


def test_the_drift_fit_writes_its_constants_and_a_two_fold_check(tmp_path: Path) -> None:
    code = main([
        "bench", "--out", str(tmp_path), "consistency", "--fit-drift", "--seeds", "4", "--estimator-frames",
        "160", "--flights", "agile",
    ])  # fmt: skip
    assert code in (0, None)
    result = json.loads((tmp_path / "consistency.json").read_text())
    assert result["seeds"] == [0, 1] and len(result["two_fold"]) == 2
    assert result["fitted"]["drift_per_pair"] > 0.0 and result["fitted"]["MIN_VAR_XY_M2"] > 0.0
    in_use = PublishedUncertainty().drift_per_pair
    assert result["in_use"]["drift_per_pair"] == pytest.approx(in_use, rel=1e-3)
    # maximum likelihood scales the model until its own samples' mean NEES is about the dof (2)
    assert result["fitted_score"]["agile"]["mean_nees"] == pytest.approx(2.0, rel=0.1)
