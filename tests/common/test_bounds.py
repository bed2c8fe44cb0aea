"""Declared field bounds: one check for every settings dataclass, one clear line naming what is wrong."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.bounds import Bounded, bounded, check_duration, field_bounds
from common.errors import InputError


@dataclass(frozen=True)
class _Example(Bounded):
    rate_hz: float = bounded(10.0, gt=0.0)
    fraction: float = bounded(0.5, ge=0.0, le=1.0)
    count: int = bounded(3, ge=1, lt=100)
    spread_m: float | None = bounded(None, gt=0.0, optional=True)
    label: str = "x"


def test_defaults_pass_and_only_bounded_fields_are_declared() -> None:
    assert _Example().rate_hz == 10.0
    assert set(field_bounds(_Example)) == {"rate_hz", "fraction", "count", "spread_m"}


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_a_value_passes_iff_it_is_finite_and_inside(rate_hz: float, fraction: float) -> None:
    inside = math.isfinite(rate_hz) and rate_hz > 0 and math.isfinite(fraction) and 0.0 <= fraction <= 1.0
    if inside:
        _Example(rate_hz=rate_hz, fraction=fraction)
    else:
        with pytest.raises(InputError, match=r"_Example\.(rate_hz|fraction) must be a finite number"):
            _Example(rate_hz=rate_hz, fraction=fraction)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"count": 100}, r"count must be a finite number >= 1 and < 100, got 100"),
     ({"count": True}, "count"), ({"rate_hz": "10"}, "rate_hz"), ({"spread_m": 0.0}, "spread_m"),
     ({"fraction": None}, "fraction")],
)  # fmt: skip
def test_out_of_bounds_bools_strings_and_none_are_refused(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(InputError, match=match):
        _Example(**kwargs)  # type: ignore[arg-type]


def test_optional_lets_none_pass() -> None:
    assert _Example(spread_m=None).spread_m is None
    assert _Example(spread_m=0.5).spread_m == 0.5


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_check_duration_passes_iff_finite_and_not_negative(dt_s: float) -> None:
    if math.isfinite(dt_s) and dt_s >= 0.0:
        assert check_duration(dt_s) == dt_s
    else:
        with pytest.raises(InputError, match="dt_s must be finite and >= 0"):
            check_duration(dt_s)
