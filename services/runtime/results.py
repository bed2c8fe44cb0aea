"""A share on the wire and back: the :class:`~common.wire.messages.PatchJob` a sender builds for it, and
:class:`~common.wire.messages.PatchResult` <-> :class:`~common.yaw.measurement.PatchMeasurement` (members
reply with it, the scatter reads it)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from common.wire.messages import BlockJob, PatchJob, PatchResult
from common.yaw.measurement import PatchMeasurement

if TYPE_CHECKING:  # round.py imports this module
    from services.runtime.round import FrameWork


def job_of(
    job_type: type[PatchJob],
    of: PatchJob | FrameWork,
    indices: np.ndarray,
    crops: np.ndarray,
    prev_indices: np.ndarray,
    prev_crops: np.ndarray,
    budget_s: float,
    **extra: Any,
) -> PatchJob:
    """The job for patches ``indices`` of the frames ``of`` names (a scatter round's frame, or the job a
    foreman received), with their crops and the previous crops of ``prev_indices`` (``extra``: a band's
    fields, ``transient``); shared by the scatter and the refinement's parts. Built from our own validated
    data without re-validation: the receiver validates at its boundary."""
    return job_type.model_construct(
        stream=of.stream,
        seq=of.seq,
        prev_seq=of.prev_seq,
        settings=of.settings,
        indices=indices.astype(np.int32, copy=False),
        crops=crops,
        prev_indices=prev_indices.astype(np.int32, copy=False),
        prev_crops=prev_crops,
        budget_s=budget_s,
        **extra,
    )


def measurement_of(result: PatchResult) -> PatchMeasurement:
    """The measurement a member's reply carries."""
    return PatchMeasurement(
        indices=np.asarray(result.indices, dtype=np.intp),
        shift_px=np.asarray(result.shift_px, dtype=np.float64),
        confidence=np.asarray(result.confidence, dtype=np.float64),
        peak=np.asarray(result.peak, dtype=np.float64),
        valid=np.asarray(result.valid, dtype=np.bool_),
    )


def result_from_measurement(
    result_type: type[PatchResult],
    job: PatchJob | BlockJob,
    member: str,
    measurement: PatchMeasurement,
    compute_s: float,
    members: dict[str, int],
    speeds: dict[str, float],
) -> PatchResult:
    """The reply message for a job from its measurement (shared by workers and foremen).

    Built without re-validation (the arrays come from the core with the wire dtypes); the receiver
    validates at its boundary.
    """
    return result_type.model_construct(
        stream=job.stream,
        seq=job.seq,
        prev_seq=job.prev_seq,
        member=member,
        indices=np.asarray(measurement.indices, dtype=np.int32),
        shift_px=np.asarray(measurement.shift_px, dtype=np.float64).reshape(-1, 2),
        confidence=np.asarray(measurement.confidence, dtype=np.float64),
        peak=np.asarray(measurement.peak, dtype=np.float64),
        valid=np.asarray(measurement.valid, dtype=np.bool_),
        compute_s=compute_s,
        members=members,
        speeds=speeds,
    )
