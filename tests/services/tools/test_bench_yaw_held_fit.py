"""``bench consistency --fit-yaw-held``: the terms of a held yaw pair's variance per pair, and the fit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.provenance import Provenance
from common.sim.field import field_flight
from common.yaw import YawSettings, honest
from services.tools.bench.consistency_runs import with_glare
from services.tools.bench.yaw_field import run_core
from services.tools.bench.yaw_held_fit import held_terms
from services.tools.cli import main

pytestmark = [pytest.mark.slow]


def test_the_terms_read_per_held_pair_rebuild_the_published_variance() -> None:
    """With the constants in use, ``terms @ coefficients`` is each held pair's published variance: the three
    runs isolate the terms (and the constants are restored after them)."""
    errors, terms = held_terms(seed=5, frames=40, glare=0.2, scenarios=["checkerboard"])
    flight = field_flight("checkerboard", seed=5, n_frames=40)
    frames = with_glare(list(flight.frames()), 0.2, 5, 0)
    series = run_core(flight, YawSettings(), frames, False)
    held = np.array([p is Provenance.HELD for p in series.provenance])
    held[: int(np.argmax(~held))] = False  # held before any pair was measured: nothing to hold, not fitted
    assert terms.shape == (errors.size, 3) and errors.size >= 4
    assert terms @ honest.held_coefficients() == pytest.approx(np.asarray(series.delta_variance_rad2)[held])
    assert np.all(terms[:, 1:] > 0.0) and np.all(terms[:, 0] >= 0.0)


def test_the_fit_writes_its_constants_and_a_two_fold_check(tmp_path: Path) -> None:
    code = main([
        "bench", "--out", str(tmp_path), "consistency", "--fit-yaw-held", "--seeds", "4", "--field-frames",
        "30", "--glare", "0.2", "--scenarios", "checkerboard", "field",
    ])  # fmt: skip
    assert code in (0, None)
    result = json.loads((tmp_path / "consistency.json").read_text())
    assert result["seeds"] == [0, 1] and result["glare"] == 0.2 and len(result["two_fold"]) == 2
    assert all(v >= 0 for v in result["fitted"].values())
    # maximum likelihood scales the model until its own samples' mean NEES is about 1
    assert result["fitted_score"]["mean_nees"] == pytest.approx(1.0, abs=0.1)
    assert result["in_use"]["HELD_ACCEL_DEG_S2"] == pytest.approx(honest.HELD_ACCEL_DEG_S2, abs=1e-3)
