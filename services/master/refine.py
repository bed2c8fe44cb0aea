"""A turning frame's second pass on the members (:data:`common.yaw.stages.RefineMeasure`).

A patch fit that turns more than ``refine_min_deg`` is measured again on frame k turned back by it. The master
warps the level image and cuts the refined patches' crops (what the in-process core does); the shifts are
measured by the members that measured those patches in the frame's first pass, as transient jobs
(:mod:`services.runtime.transient`): a member that lies there lies about the same patches, which the robust
fit already outvotes. A foreman holds its block's previous crops; a worker is sent them. What no active member
measured, or a member failed, the master measures itself, so a frame is never lost to it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import zenoh

from common.dispatch import SELF, Dispatcher
from common.wire import keys
from common.wire.messages import BlockJob, PatchJob, PatchResult
from common.yaw import PatchGrid, YawSettings
from common.yaw.grid import IntArray, U8Array
from common.yaw.measurement import PatchMeasurement, merge_measurements
from common.yaw.patchwork import measure_crops
from services.runtime.counters import Counters
from services.runtime.round import FrameWork, RoundReport
from services.runtime.transient import TransientPart, gather, send_parts, transient_job


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
    ) -> MemberRefine | None:
        """The second pass of the frame ``work`` whose first pass ``report`` tells, or None (refined here as
        in-process) when the master measured every patch itself. A pass of fewer than ``min_px`` level
        pixels (``refine_on_members_pixels``) is measured here too."""
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
            session, grid, prev_level, work, settings, *job_types, owners, dispatcher, counters, min_px
        )

    def __call__(self, indices: IntArray, crops_u8: U8Array) -> PatchMeasurement:
        if crops_u8.size < self.min_px:  # a round trip would cost more latency than the compute here
            self.counters.inc("refine_patches_here", int(indices.size))
            return self._here(indices, crops_u8, np.arange(indices.size))
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
        measured = [self._here(indices, crops_u8, here)] if here.size else []
        for r, got in zip(rows, gather(sent, self.result_type, self.counters), strict=True):
            measured.append(self._here(indices, crops_u8, r) if got is None else got)
        if here.size:
            self.counters.inc("refine_patches_here", int(here.size))
        return merge_measurements(measured, indices)

    def _prev_for(self, indices: IntArray) -> U8Array | None:
        """The previous crops a member needs sent: a worker's (a foreman holds its block's)."""
        return None if self.job_type is BlockJob else self.grid.crop_level(self.prev_level, indices)

    def _here(self, indices: IntArray, crops_u8: U8Array, rows: IntArray) -> PatchMeasurement:
        idx = indices[rows]
        return measure_crops(self.settings, idx, crops_u8[rows], self.grid.crop_level(self.prev_level, idx))


__all__ = ["MemberRefine"]
