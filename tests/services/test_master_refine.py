"""Where a turning frame's second pass runs (:meth:`services.master.refine.MemberRefine.of`): on the members
that measured its patches when it covers at least ``refine_on_members_pixels`` level pixels and the members
have cost less than the master (:mod:`common.dispatch.refine_place`), else on the master, as in-process (the
defaults' 40 patches of 32 px: a round trip costs more latency than it saves)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
import zenoh

from common.dispatch import SELF, Dispatcher, DispatchSettings
from common.dispatch.refine_place import RefineCosts, RefinePlace
from common.wire.messages import BlockJob, BlockResult, YawJobSettings
from common.yaw import YawSettings, for_frame, make_patch_grid
from common.yaw.measurement import PatchMeasurement
from services.master import refine as refine_module
from services.master.refine import MemberRefine, RefineChooser
from services.master.settings import MasterSettings
from services.runtime.counters import Counters
from services.runtime.round import FrameWork, RoundReport


def _part(indices: np.ndarray) -> PatchMeasurement:
    n = indices.size
    return PatchMeasurement(indices, np.zeros((n, 2)), np.ones(n), np.ones(n), np.ones(n, bool))


class _Unreachable:
    """A session whose every query fails (zenoh's error for a closing session), counted."""

    def __init__(self) -> None:
        self.queries = 0

    def get(self, *args: Any, **kwargs: Any) -> Any:
        self.queries += 1
        raise zenoh.ZError("session closing")


def _of(
    settings: YawSettings,
    owners: list[str],
    min_px: int,
    chooser: RefineChooser | None = None,
    computes: bool = False,
) -> MemberRefine | None:
    settings = for_frame(settings, (480, 752))
    grid = make_patch_grid((480, 752), settings)
    halves = np.array_split(grid.all_indices, len(owners))
    report = RoundReport(parts=[_part(h) for h in halves], owners=owners)
    work = FrameWork(
        stream="uav0", seq=2, prev_seq=1, settings=YawJobSettings.of(settings), budget_s=1.0,
        crops=lambda i: pytest.fail("not cut here"), prev_crops=lambda i: pytest.fail("not cut here"),
        compute_self=lambda i, m: pytest.fail("not computed here"),
    )  # fmt: skip
    session: Any = _Unreachable()  # a query fails as on a closing session: its part is measured here
    level = np.zeros((480 >> settings.level, 752 >> settings.level), np.uint8)
    dispatcher = Dispatcher(DispatchSettings(self_compute=computes), grid.n_patches)
    for member in owners:
        if member != SELF:
            dispatcher.join(member)
    return MemberRefine.of(
        session, grid, level, work, (BlockJob, BlockResult), report, dispatcher, Counters(), min_px,
        chooser or RefineChooser(),
    )  # fmt: skip


def test_the_defaults_refine_on_the_master_and_large_patches_on_the_members() -> None:
    default_px = MasterSettings().refine_on_members_pixels
    members = ["foreman/h1/0", "foreman/h2/0"]
    small = _of(YawSettings(), members, default_px)
    assert small is not None
    # 40 x 32^2 = 40960 px: measured here (a session that is asked anything fails the test)
    indices = np.arange(40)
    crops = np.random.default_rng(0).integers(0, 256, (40, 32, 32), dtype=np.uint8)
    assert small(indices, crops).indices.size == 40
    assert small.counters.get("refine_patches_here") == 40
    large = YawSettings(grid_cols=16, grid_rows=12, patch_size_px=128, pyramid_level=0)
    refine = _of(large, members, default_px)  # 48 x 128^2 px: on the members
    assert refine is not None and set(refine.owners.values()) == set(members) and len(refine.owners) == 192
    assert 48 * 128**2 >= default_px > 40 * 32**2


def test_a_frame_the_master_measured_alone_is_refined_on_the_master() -> None:
    assert _of(YawSettings(), [SELF], 0) is None
    refine = _of(YawSettings(), [SELF, "worker/h1/0"], 0)
    assert refine is not None and set(refine.owners.values()) == {"worker/h1/0"}


class _SteppingClock:
    """``perf_counter`` that reads ``step_s`` later at each call (``monotonic`` is the real one): the pass's
    measured time is then known exactly, however busy the host is."""

    def __init__(self, step_s: float) -> None:
        self.step_s = step_s
        self.now_s = 0.0
        self.monotonic = time.monotonic

    def perf_counter(self) -> float:
        self.now_s += self.step_s
        return self.now_s


def test_a_large_pass_stays_on_a_computing_master_where_the_members_have_cost_more(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On a fast CPU over 100 Mbit the members' raw crops cost more than the master's compute (1080p turns:
    1.26 times one host's latency with the pass sent): a master that computes shares keeps the pass, and the
    decision is counted. (One that only dispatches sends it regardless: its CPU is the dispatch's.)"""
    clock = _SteppingClock(0.024)  # the kept pass reads the clock twice: 0.024 s for its 48 patches
    monkeypatch.setattr(refine_module, "time", clock)
    large = YawSettings(grid_cols=16, grid_rows=12, patch_size_px=128, pyramid_level=0)
    members = ["foreman/h1/0", "foreman/h2/0"]
    chooser = RefineChooser(costs=RefineCosts(here_s_per_patch=2e-4, members_s_per_patch=9e-4))
    assert _of(large, members, 0, chooser).chooser.choose() is RefinePlace.HERE  # type: ignore[union-attr]
    refine = _of(large, members, 0, chooser, computes=True)
    assert refine is not None
    indices = np.arange(0, 192, 4)
    crops = np.random.default_rng(1).integers(0, 256, (indices.size, 128, 128), dtype=np.uint8)
    assert refine(indices, crops).indices.size == indices.size  # a session asked anything fails the test
    assert refine.counters.get("refine_passes_kept_here") == 1
    assert refine.counters.get("refine_patches_here") == indices.size
    # the pass's own time (0.5 ms a patch) enters the master's running cost with the chooser's memory (0.3)
    assert chooser.costs.since_probe == 1
    assert chooser.costs.here_s_per_patch == pytest.approx(0.7 * 2e-4 + 0.3 * 0.024 / 48)


def test_a_master_that_only_dispatches_sends_the_pass_whatever_it_has_cost() -> None:
    large = YawSettings(grid_cols=16, grid_rows=12, patch_size_px=128, pyramid_level=0)
    chooser = RefineChooser(costs=RefineCosts(here_s_per_patch=2e-4, members_s_per_patch=9e-4))
    refine = _of(large, ["foreman/h1/0", "foreman/h2/0"], 0, chooser)
    assert refine is not None
    indices = np.arange(0, 192, 4)
    crops = np.random.default_rng(2).integers(0, 256, (indices.size, 128, 128), dtype=np.uint8)
    assert refine(indices, crops).indices.size == indices.size
    assert refine.session.queries == 2  # one part a member (both failed: measured here)
    assert refine.counters.get("refine_patches_sent") == indices.size
    assert refine.counters.get("refine_failures") == 2
    assert not refine.counters.get("refine_passes_kept_here")
    assert chooser.costs == RefineCosts(here_s_per_patch=2e-4, members_s_per_patch=9e-4)  # not its call
