"""Where a turning frame's second pass runs (:mod:`common.dispatch.refine_place`): the members until measured,
then the master, then the cheaper place, with the other one measured again every ``probe_every`` passes."""

from __future__ import annotations

import math
from itertools import pairwise

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.dispatch.refine_place import (
    RefineCosts,
    RefinePlace,
    RefinePlaceSettings,
    choose_place,
    observe_pass,
)
from common.errors import InputError

HERE, MEMBERS = RefinePlace.HERE, RefinePlace.MEMBERS


def _run(here_s: float, members_s: float, passes: int, cfg: RefinePlaceSettings) -> list[RefinePlace]:
    """Places chosen over ``passes`` passes of 48 patches whose true costs per patch are the given ones (the
    master's own part of a sent pass: a third of it, at its own cost)."""
    costs, places = RefineCosts(), []
    for _ in range(passes):
        place = choose_place(costs, cfg)
        places.append(place)
        if place is HERE:
            costs = observe_pass(costs, cfg, HERE, 48, 48 * here_s)
        else:
            costs = observe_pass(costs, cfg, MEMBERS, 48, 48 * members_s, 16, 16 * here_s)
    return places


def test_the_members_are_measured_first_then_the_master() -> None:
    cfg = RefinePlaceSettings()
    costs = RefineCosts()
    assert choose_place(costs, cfg) is MEMBERS
    costs = observe_pass(costs, cfg, MEMBERS, 48, 0.048)  # the master had no part: still unknown
    assert math.isnan(costs.here_s_per_patch) and choose_place(costs, cfg) is HERE
    costs = observe_pass(costs, cfg, HERE, 48, 0.0096)
    assert choose_place(costs, cfg) is HERE and costs.cheaper() is HERE


def test_a_sent_pass_with_the_masters_part_tells_what_the_master_costs() -> None:
    cfg = RefinePlaceSettings()
    costs = observe_pass(RefineCosts(), cfg, MEMBERS, 48, 0.048, 36, 0.0072)
    assert costs.here_s_per_patch == pytest.approx(0.0002)
    assert choose_place(costs, cfg) is HERE


@settings(max_examples=40, deadline=None)
@given(
    here_ms=st.floats(0.05, 5.0),
    ratio=st.one_of(st.floats(0.2, 0.8), st.floats(1.25, 5.0)),
    probe_every=st.integers(2, 32),
)
def test_the_cheaper_place_is_taken_and_the_other_probed_every_n_passes(
    here_ms: float, ratio: float, probe_every: int
) -> None:
    cfg = RefinePlaceSettings(probe_every=probe_every)
    members_ms = here_ms * ratio
    cheaper = HERE if here_ms < members_ms else MEMBERS
    places = _run(here_ms * 1e-3, members_ms * 1e-3, 200, cfg)
    settled = places[2:]  # both measured after at most two passes
    dearer = [i for i, p in enumerate(settled) if p is not cheaper]
    # then exactly one pass in probe_every goes to the dearer place
    assert len(settled) // probe_every <= len(dearer) <= len(settled) // probe_every + 1
    assert all(b - a == probe_every for a, b in pairwise(dearer))


def test_a_link_that_becomes_slow_moves_the_pass_back_to_the_master() -> None:
    cfg = RefinePlaceSettings()
    costs = RefineCosts()
    for _ in range(40):  # members cheaper: 0.1 ms a patch against 0.2 here
        place = choose_place(costs, cfg)
        costs = observe_pass(costs, cfg, place, 48, 48 * (1e-4 if place is MEMBERS else 2e-4))
    assert choose_place(costs, cfg) is MEMBERS or costs.since_probe + 1 >= cfg.probe_every
    for _ in range(3 * cfg.probe_every):  # the link thins: 1 ms a patch on the members
        place = choose_place(costs, cfg)
        costs = observe_pass(costs, cfg, place, 48, 48 * (1e-3 if place is MEMBERS else 2e-4))
    assert costs.cheaper() is HERE


@pytest.mark.parametrize(
    ("patches", "seconds", "here"),
    [(0, 0.01, (0, 0.0)), (4, math.nan, (0, 0.0)), (4, -1.0, (0, 0.0)), (4, 0.01, (-1, 0.0)),
     (4, 0.01, (1, math.inf))],
)  # fmt: skip
def test_a_pass_that_is_not_one_is_refused(patches: int, seconds: float, here: tuple[int, float]) -> None:
    with pytest.raises(InputError):
        observe_pass(RefineCosts(), RefinePlaceSettings(), MEMBERS, patches, seconds, *here)
