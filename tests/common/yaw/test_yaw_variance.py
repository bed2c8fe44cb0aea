"""The yaw's variance with measured pairs correlated in time (:mod:`common.yaw.yaw_variance`): the
recursion is the sum of the pairs' covariance."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.provenance import Provenance
from common.yaw.yaw_variance import (
    CORRELATED_SHARE,
    CORRELATION_TIME_S,
    PairErrorModel,
    YawVariance,
    add_pair_variance,
    pair_covariance_rad2,
)

pairs = st.lists(
    st.tuples(st.floats(1e-12, 1e-2), st.floats(1e-3, 0.5), st.sampled_from(list(Provenance))),
    min_size=1,
    max_size=40,
)


@settings(max_examples=80, deadline=None)
@given(pairs)
def test_the_recursion_is_the_sum_of_the_pairs_covariance_at_every_frame(
    run: list[tuple[float, float, Provenance]],
) -> None:
    """What the tracker carries (the yaw's variance and the two memories) gives at every frame the sum of
    the run's covariance so far, in O(1) a frame."""
    variances = np.array([v for v, _, _ in run])
    stops = np.cumsum([step for _, step, _ in run])
    covariance = pair_covariance_rad2(variances, stops, [p for _, _, p in run])
    yaw_variance = YawVariance()
    for k, (v, step, provenance) in enumerate(run):
        yaw_variance = add_pair_variance(yaw_variance, v, step, provenance)
        expected = covariance[: k + 1, : k + 1].sum()
        assert yaw_variance.variance_rad2 == pytest.approx(expected, rel=1e-9, abs=1e-300)
    # positive correlation only: never below the independent sum, and the covariance is a covariance
    assert yaw_variance.variance_rad2 >= variances.sum() * (1.0 - 1e-12)
    assert np.linalg.eigvalsh(covariance).min() >= -1e-12 * variances.max()


def test_a_bridged_pair_adds_its_variance_the_measured_memory_decays_a_hold_adds_up() -> None:
    after_measured = add_pair_variance(YawVariance(), 4e-6, 0.05, Provenance.MEASURED)
    assert after_measured.variance_rad2 == pytest.approx(4e-6)
    assert after_measured.measured_memory_rad == pytest.approx(math.sqrt(CORRELATED_SHARE * 4e-6))
    bridged = add_pair_variance(after_measured, 1e-6, 0.05, Provenance.BRIDGED)
    assert bridged.variance_rad2 == pytest.approx(5e-6)
    decay = math.exp(-0.05 / CORRELATION_TIME_S)
    assert bridged.measured_memory_rad == pytest.approx(after_measured.measured_memory_rad * decay)
    # two held pairs of one hold: their errors add up (std 1e-3 + 2e-3), then a measured pair ends the hold
    held = add_pair_variance(
        add_pair_variance(YawVariance(), 1e-6, 0.05, Provenance.HELD), 4e-6, 0.05, Provenance.HELD
    )
    assert held.variance_rad2 == pytest.approx((1e-3 + 2e-3) ** 2)
    assert add_pair_variance(held, 1e-6, 0.05, Provenance.MEASURED).held_memory_rad == 0.0


def test_steady_pairs_grow_the_variance_by_the_long_run_factor() -> None:
    """Equal pairs at a steady rate: each adds ``v (1 + 2 q phi / (1 - phi))`` once the memory settles."""
    v, step = 1e-6, 0.05
    yaw_variance = YawVariance()
    increments = []
    for _ in range(400):
        before = yaw_variance.variance_rad2
        yaw_variance = add_pair_variance(yaw_variance, v, step, Provenance.MEASURED)
        increments.append(yaw_variance.variance_rad2 - before)
    phi = math.exp(-step / CORRELATION_TIME_S)
    assert increments[0] == pytest.approx(v)
    assert increments[-1] == pytest.approx(v * (1.0 + 2.0 * CORRELATED_SHARE * phi / (1.0 - phi)))


@pytest.mark.parametrize(("variance", "step"), [(math.nan, 0.05), (-1e-6, 0.05), (1e-6, -0.01)])
def test_bad_input_is_refused(variance: float, step: float) -> None:
    with pytest.raises(InputError):
        add_pair_variance(YawVariance(), variance, step, Provenance.MEASURED)
    with pytest.raises(InputError):
        YawVariance(1e-6, -1.0)


def test_a_covariance_of_mismatched_arrays_or_a_share_beyond_one_is_refused() -> None:
    with pytest.raises(InputError):
        pair_covariance_rad2([1e-6, 1e-6], [0.05], [Provenance.MEASURED] * 2)
    with pytest.raises(InputError):
        pair_covariance_rad2([math.nan], [0.05], [Provenance.MEASURED])
    for share, time_s in ((1.5, 0.2), (0.5, 0.0), (0.5, math.inf)):
        with pytest.raises(InputError):
            PairErrorModel(share, time_s)
