"""Rates of a stream (``capataz hz``) and of counters (``capataz status``)."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.errors import InputError
from common.rates import counter_rates, interval_stats


def test_a_regular_stream_has_its_rate_and_no_spread() -> None:
    figures = interval_stats([10.0 + 0.05 * i for i in range(21)])
    assert figures is not None
    assert figures.messages == 21
    assert figures.rate_hz == pytest.approx(20.0)
    assert figures.min_s == pytest.approx(0.05) and figures.max_s == pytest.approx(0.05)
    assert figures.std_s == pytest.approx(0.0, abs=1e-12)


def test_an_irregular_stream_has_its_extremes_and_spread() -> None:
    figures = interval_stats([0.0, 0.1, 0.4, 0.5])  # intervals 0.1, 0.3, 0.1
    assert figures is not None
    assert figures.rate_hz == pytest.approx(3 / 0.5)
    assert (figures.min_s, figures.max_s) == pytest.approx((0.1, 0.3))
    assert figures.std_s == pytest.approx(np.std([0.1, 0.3, 0.1]))


def test_fewer_than_two_arrivals_have_no_figures() -> None:
    assert interval_stats([]) is None
    assert interval_stats([1.0]) is None


@pytest.mark.parametrize("times", [[1.0, 0.5], [0.0, math.nan], [[0.0, 1.0]]])
def test_bad_arrival_times_are_refused(times: list) -> None:
    with pytest.raises(InputError):
        interval_stats(times)


@given(st.lists(st.floats(0.0, 10.0), min_size=1, max_size=50), st.floats(-1e3, 1e3))
def test_figures_are_the_intervals_and_do_not_depend_on_the_origin(gaps: list[float], origin: float) -> None:
    times = origin + np.concatenate([[0.0], np.cumsum(gaps)])
    figures = interval_stats(times.tolist())
    assert figures is not None
    intervals = np.diff(times)
    assert figures.min_s <= figures.mean_s + 1e-9 and figures.mean_s <= figures.max_s + 1e-9
    assert figures.mean_s == pytest.approx(float(intervals.mean()), abs=1e-9)
    if figures.mean_s > 1.0 / sys.float_info.max:
        assert figures.rate_hz * figures.mean_s == pytest.approx(1.0)
    else:  # all arrivals at one time, or a mean whose inverse overflows (2e-311 s, found by hypothesis)
        assert figures.rate_hz == math.inf


@given(
    st.dictionaries(st.sampled_from(["a", "b", "c"]), st.integers(0, 10**6)),
    st.dictionaries(st.sampled_from(["a", "b", "c", "d"]), st.integers(0, 10**6)),
    st.floats(0.01, 100.0),
)
def test_counter_rates_give_back_the_later_counters(earlier: dict, growth: dict, elapsed_s: float) -> None:
    later = {k: earlier.get(k, 0) + v for k, v in growth.items()}
    rates = counter_rates(earlier, later, elapsed_s)
    assert set(rates) == set(later)
    for name, rate in rates.items():
        assert earlier.get(name, 0) + rate * elapsed_s == pytest.approx(later[name])


def test_a_counter_that_went_down_has_no_rate() -> None:
    assert counter_rates({"frames_in": 100, "malformed": 1}, {"frames_in": 3, "malformed": 3}, 2.0) == {
        "malformed": 1.0
    }


@pytest.mark.parametrize("elapsed_s", [0.0, -1.0, math.inf, math.nan])
def test_counter_rates_need_a_positive_time(elapsed_s: float) -> None:
    with pytest.raises(InputError):
        counter_rates({}, {"a": 1}, elapsed_s)
