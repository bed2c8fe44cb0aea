"""A turning frame's second pass on the members (:data:`common.yaw.stages.RefineMeasure`).

A patch fit that turns more than ``refine_min_deg`` is measured again on frame k turned back by it. The master
warps the level image and cuts the refined patches' crops (what the in-process core does); the shifts are
measured by the members that measured those patches in the frame's first pass, as transient jobs
(:mod:`services.runtime.transient`): a member that lies there lies about the same patches, which the robust
fit already outvotes. A foreman holds its block's previous crops; a worker is sent them. What no active member
measured, or a member failed, the master measures itself, so a frame is never lost to it. Whether a pass goes
to the members at all is chosen by what each place has cost the stream's passes so far
(:mod:`common.dispatch.refine_place`): the raw crops can cost more on the link than they save.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import zenoh

from common.dispatch import SELF, Dispatcher
from common.dispatch.refine_place import (
    RefineCosts,
    RefinePlace,
    RefinePlaceSettings,
    choose_place,
    observe_pass,
)
from common.wire import keys
from common.wire.messages import BlockJob, PatchJob, PatchResult
from common.yaw import PatchGrid, YawSettings
from common.yaw.grid import IntArray, U8Array
from common.yaw.measurement import PatchMeasurement, merge_measurements
from common.yaw.patchwork import measure_crops
from services.runtime.counters import Counters
from services.runtime.round import FrameWork, RoundReport
from services.runtime.transient import TransientPart, gather, send_parts, transient_job

logger = logging.getLogger(__name__)


@dataclass
class RefineChooser:
    """A stream's running costs of its second passes' two places (used by the master's frame thread alone)."""

    settings: RefinePlaceSettings = field(default_factory=RefinePlaceSettings)
    costs: RefineCosts = field(default_factory=RefineCosts)

    def choose(self) -> RefinePlace:
        return choose_place(self.costs, self.settings)

    def observe(
        self, place: RefinePlace, patches: int, seconds: float, here: tuple[int, float] = (0, 0.0)
    ) -> None:
        """A pass of ``patches`` at ``place`` took ``seconds``; ``here``: the master's own part of a pass sent
        to the members (patches, seconds)."""
        before = self.costs.cheaper()
        self.costs = observe_pass(self.costs, self.settings, place, patches, seconds, *here)
        after = self.costs.cheaper()
        if after is not None and after is not before:
            logger.info(
                "turning frames' second pass: %s from now on (a patch cost %.2f ms here, %.2f ms on the "
                "members; the other place is measured again every %d passes)",
                "on the master" if after is RefinePlace.HERE else "on the members",
                self.costs.here_s_per_patch * 1e3,
                self.costs.members_s_per_patch * 1e3,
                self.settings.probe_every,
            )


@dataclass(frozen=True)
class MemberRefine:
    """Measures a frame's refined patches on the members that measured them, if still active."""

    session: zenoh.Session
    grid: PatchGrid
    prev_level: U8Array
    work: FrameWork
    settings: YawSettings
    job_type: type[PatchJob]
    result_type: type[PatchResult]
    #: who measured each patch in the first pass (members only)
    owners: dict[int, str]
    #: asked, when the refinement runs, which owners are still active (the guard vetted the frame)
    dispatcher: Dispatcher
    counters: Counters
    #: a pass of fewer level pixels is measured here (``refine_on_members_pixels``)
    min_px: int
    #: the stream's costs of the two places, which choose where a larger pass goes
    chooser: RefineChooser

    @classmethod
    def of(
        cls,
        session: zenoh.Session,
        grid: PatchGrid,
        prev_level: U8Array,
        work: FrameWork,
        job_types: tuple[type[PatchJob], type[PatchResult]],
        report: RoundReport,
        dispatcher: Dispatcher,
        counters: Counters,
        min_px: int,
        chooser: RefineChooser,
    ) -> MemberRefine | None:
        """The second pass of the frame ``work`` whose first pass ``report`` tells, or None (refined here as
        in-process) when the master measured every patch itself. A pass of fewer than ``min_px`` level
        pixels (``refine_on_members_pixels``) is measured here too, a larger one where ``chooser`` says."""
        owners = {
            index: owner
            for part, owner in zip(report.parts, report.owners, strict=True)
            if owner != SELF
            for index in part.indices.tolist()
        }
        if not owners:
            return None
        settings = work.settings.yaw_settings
        return cls(
            session,
            grid,
            prev_level,
            work,
            settings,
            *job_types,
            owners,
            dispatcher,
            counters,
            min_px,
            chooser,
        )

    def __call__(self, indices: IntArray, crops_u8: U8Array) -> PatchMeasurement:
        if crops_u8.size < self.min_px:  # a round trip would cost more latency than the compute here
            self.counters.inc("refine_patches_here", int(indices.size))
            return self._here(indices, crops_u8, np.arange(indices.size))
        t0 = time.perf_counter()
        # a master that computes shares (--compute) weighs the members' round trip against its compute; one
        # that only dispatches leaves every share, the second pass's too, to the members
        computes = self.dispatcher.settings.self_compute
        if computes and self.chooser.choose() is RefinePlace.HERE:  # the members' round trip cost more
            self.counters.inc("refine_passes_kept_here")
            self.counters.inc("refine_patches_here", int(indices.size))
            measurement = self._here(indices, crops_u8, np.arange(indices.size))
            self.chooser.observe(RefinePlace.HERE, int(indices.size), time.perf_counter() - t0)
            return measurement
        active = set(self.dispatcher.active(time.monotonic()))
        groups: dict[str, list[int]] = {}
        for row, index in enumerate(indices.tolist()):
            owner = self.owners.get(index, SELF)
            groups.setdefault(owner if owner in active else SELF, []).append(row)
        here = np.asarray(groups.pop(SELF, []), dtype=np.intp)
        rows = [np.asarray(r, dtype=np.intp) for r in groups.values()]
        budget_s = self.work.budget_s
        parts = [
            TransientPart(member, keys.work_key_of(member), transient_job(
                self.job_type, self.work, indices[r], crops_u8[r], self._prev_for(indices[r]), budget_s))
            for member, r in zip(groups, rows, strict=True)
        ]  # fmt: skip
        sent = send_parts(self.session, parts, budget_s)
        self.counters.inc("refine_patches_sent", sum(int(p.job.indices.size) for p in parts))
        t_here = time.perf_counter()
        measured = [self._here(indices, crops_u8, here)] if here.size else []
        here_s = time.perf_counter() - t_here
        for r, got in zip(rows, gather(sent, self.result_type, self.counters), strict=True):
            measured.append(self._here(indices, crops_u8, r) if got is None else got)
        if here.size:
            self.counters.inc("refine_patches_here", int(here.size))
        if computes:
            place = RefinePlace.MEMBERS if parts else RefinePlace.HERE  # no owner active: it all ran here
            self.chooser.observe(place, int(indices.size), time.perf_counter() - t0, (int(here.size), here_s))
        return merge_measurements(measured, indices)

    def _prev_for(self, indices: IntArray) -> U8Array | None:
        """The previous crops a member needs sent: a worker's (a foreman holds its block's)."""
        return None if self.job_type is BlockJob else self.grid.crop_level(self.prev_level, indices)

    def _here(self, indices: IntArray, crops_u8: U8Array, rows: IntArray) -> PatchMeasurement:
        idx = indices[rows]
        return measure_crops(self.settings, idx, crops_u8[rows], self.grid.crop_level(self.prev_level, idx))


__all__ = ["MemberRefine"]
