"""The yaw's variance with measured pairs correlated in time (:mod:`common.yaw.yaw_variance`): the
recursion is the sum of the pairs' covariance."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.yaw.yaw_variance import (
    CORRELATED_SHARE,
    CORRELATION_TIME_S,
    PairErrorModel,
    add_pair_variance,
    pair_covariance_rad2,
)

pairs = st.lists(
    st.tuples(st.floats(1e-12, 1e-2), st.floats(1e-3, 0.5), st.booleans()), min_size=1, max_size=40
)


@settings(max_examples=60, deadline=None)
@given(pairs)
def test_the_recursion_is_the_sum_of_the_pairs_covariance_at_every_frame(
    run: list[tuple[float, float, bool]],
) -> None:
    """What the tracker carries (the yaw's variance and the measured pairs' memory) gives at every frame the
    sum of the run's covariance so far, in O(1) a frame."""
    variances = np.array([v for v, _, _ in run])
    stops = np.cumsum([step for _, step, _ in run])
    measured = np.array([m for _, _, m in run])
    covariance = pair_covariance_rad2(variances, stops, measured)
    yaw_variance, memory = 0.0, 0.0
    for k, (v, step, m) in enumerate(run):
        yaw_variance, memory = add_pair_variance(yaw_variance, memory, v, step, m)
        assert yaw_variance == pytest.approx(covariance[: k + 1, : k + 1].sum(), rel=1e-9, abs=1e-300)
    # positive correlation only: never below the independent sum, and the covariance is a covariance
    assert yaw_variance >= variances.sum() * (1.0 - 1e-12)
    assert np.linalg.eigvalsh(covariance).min() >= -1e-12 * variances.max()


def test_bridged_and_held_pairs_add_only_their_variance_and_the_memory_decays() -> None:
    yaw_variance, memory = add_pair_variance(0.0, 0.0, 4e-6, 0.05, True)
    assert (yaw_variance, memory) == (
        pytest.approx(4e-6),
        pytest.approx(math.sqrt(CORRELATED_SHARE * 4e-6)),
    )
    after, decayed = add_pair_variance(yaw_variance, memory, 1e-6, 0.05, False)
    assert after == pytest.approx(5e-6)
    assert decayed == pytest.approx(memory * math.exp(-0.05 / CORRELATION_TIME_S))


def test_steady_pairs_grow_the_variance_by_the_long_run_factor() -> None:
    """Equal pairs at a steady rate: each adds ``v (1 + 2 q phi / (1 - phi))`` once the memory settles."""
    v, step = 1e-6, 0.05
    yaw_variance, memory = 0.0, 0.0
    increments = []
    for _ in range(400):
        before = yaw_variance
        yaw_variance, memory = add_pair_variance(yaw_variance, memory, v, step, True)
        increments.append(yaw_variance - before)
    phi = math.exp(-step / CORRELATION_TIME_S)
    assert increments[0] == pytest.approx(v)
    assert increments[-1] == pytest.approx(v * (1.0 + 2.0 * CORRELATED_SHARE * phi / (1.0 - phi)))


@pytest.mark.parametrize(
    ("variance", "step", "memory"),
    [(math.nan, 0.05, 0.0), (-1e-6, 0.05, 0.0), (1e-6, -0.01, 0.0), (1e-6, 0.05, -1.0)],
)
def test_bad_input_is_refused(variance: float, step: float, memory: float) -> None:
    with pytest.raises(InputError):
        add_pair_variance(0.0, memory, variance, step, True)


def test_a_covariance_of_mismatched_arrays_or_a_share_beyond_one_is_refused() -> None:
    with pytest.raises(InputError):
        pair_covariance_rad2([1e-6, 1e-6], [0.05], [True, True])
    with pytest.raises(InputError):
        pair_covariance_rad2([math.nan], [0.05], [True])
    for share, time_s in ((1.5, 0.2), (0.5, 0.0), (0.5, math.inf)):
        with pytest.raises(InputError):
            PairErrorModel(share, time_s)
