"""Where a turning frame's second pass runs (:meth:`services.master.refine.MemberRefine.of`): on the members
that measured its patches when it covers at least ``refine_on_members_pixels`` level pixels, else on the
master, as in-process (the defaults' 40 patches of 32 px: a round trip costs more latency than it saves)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from common.dispatch import SELF, Dispatcher, DispatchSettings
from common.wire.messages import BlockJob, BlockResult, YawJobSettings
from common.yaw import YawSettings, make_patch_grid
from common.yaw.measurement import PatchMeasurement
from services.master.refine import MemberRefine
from services.master.settings import MasterSettings
from services.runtime.counters import Counters
from services.runtime.round import FrameWork, RoundReport


def _part(indices: np.ndarray) -> PatchMeasurement:
    n = indices.size
    return PatchMeasurement(indices, np.zeros((n, 2)), np.ones(n), np.ones(n), np.ones(n, bool))


def _of(settings: YawSettings, owners: list[str], min_px: int) -> MemberRefine | None:
    grid = make_patch_grid((480, 752), settings)
    halves = np.array_split(grid.all_indices, len(owners))
    report = RoundReport(parts=[_part(h) for h in halves], owners=owners)
    work = FrameWork(
        stream="uav0", seq=2, prev_seq=1, settings=YawJobSettings.of(settings), budget_s=1.0,
        crops=lambda i: pytest.fail("not cut here"), prev_crops=lambda i: pytest.fail("not cut here"),
        compute_self=lambda i, m: pytest.fail("not computed here"),
    )  # fmt: skip
    session: Any = None  # nothing is sent while deciding
    level = np.zeros((480 >> settings.pyramid_level, 752 >> settings.pyramid_level), np.uint8)
    dispatcher = Dispatcher(DispatchSettings(), grid.n_patches)
    return MemberRefine.of(
        session, grid, level, work, (BlockJob, BlockResult), report, dispatcher, Counters(), min_px
    )


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
