"""A share's measurement on the wire and back: :class:`~common.wire.messages.PatchResult` <->
:class:`~common.yaw.measurement.PatchMeasurement` (members reply with it, the scatter reads it)."""

from __future__ import annotations

import numpy as np

from common.wire.messages import BlockJob, PatchJob, PatchResult
from common.yaw.measurement import PatchMeasurement


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
