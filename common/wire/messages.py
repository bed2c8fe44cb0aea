"""Every message on the wire: sensors, estimates, work and service messages (the rig's:
:mod:`common.wire.rig`; the work messages' home is :mod:`common.wire.jobs`, re-exported here).

Their base and bounds: :mod:`common.wire.schema`; the one codec that carries them and their registry:
:mod:`common.wire.codec`.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from common.provenance import Provenance
from common.wire.frame_codec import FrameEncoding
from common.wire.jobs import LOCAL_YAW_SETTINGS as LOCAL_YAW_SETTINGS
from common.wire.jobs import BlockJob as BlockJob
from common.wire.jobs import BlockResult as BlockResult
from common.wire.jobs import PatchJob as PatchJob
from common.wire.jobs import PatchResult as PatchResult
from common.wire.jobs import YawJobSettings as YawJobSettings
from common.wire.schema import (
    MAX_FRAME_SIDE_PX,
    MAX_SEQ,
    RIG_ID_PATTERN,
    ArraySpec,
    Uav,
    WireModel,
    frame_id_field,
)


# ----------------------------------------------------------------------------------------------- sensors
class UavMessage(WireModel):
    """A message of one UAV's stream: its id, the sequence number and the stamp of what it carries."""

    uav: Uav
    seq: int = Field(ge=0, le=MAX_SEQ, default=0)
    stamp_s: float


class Frame(UavMessage):
    """One camera image of a UAV stream (8-bit grey, row-major ``(height, width)``). ``encoding`` is how the
    pixels travel (:mod:`common.wire.frame_codec`): compressed, as the 1-D array ``COMPRESSED_NAME`` that the
    codec decodes once at decode, so a received frame always holds its ``pixels``."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {"pixels": ArraySpec("|u1", (None, None))}
    #: the wire array of a compressed frame: its codec's bytes
    COMPRESSED_NAME: ClassVar[str] = "compressed"
    COMPRESSED_SPEC: ClassVar[ArraySpec] = ArraySpec("|u1", (None,))
    seq: int = Field(ge=0, le=MAX_SEQ)  # required
    width: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    height: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    encoding: FrameEncoding = "mono8"
    #: the JPEG quality the pixels travel at (jpeg only; None: ``DEFAULT_JPEG_QUALITY``)
    quality: int | None = Field(default=None, ge=1, le=100)
    pixels: np.ndarray
    frame_id: str = frame_id_field("camera")
    #: the id of the stream's rig (``common.wire.rig.RigMessage``) it was taken with; None: not stated
    rig_id: str | None = Field(default=None, pattern=RIG_ID_PATTERN)

    @model_validator(mode="after")
    def _shape_matches(self) -> Frame:
        if self.pixels.shape != (self.height, self.width):
            raise ValueError(
                f"pixels: shape {self.pixels.shape} != (height, width) = ({self.height}, {self.width})"
            )
        if self.quality is not None and self.encoding != "jpeg":
            raise ValueError(f"quality: only a jpeg frame has one, not a {self.encoding} frame")
        return self


class ImuSample(UavMessage):
    """One IMU reading in the body frame (FLU): angular rate and specific force."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "gyro_rad_s": ArraySpec("<f8", (3,)),
        "accel_m_s2": ArraySpec("<f8", (3,)),
    }
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    frame_id: str = frame_id_field("body")


class RangeSample(UavMessage):
    """One rangefinder reading along body -z."""

    range_m: float = Field(gt=0.0)
    frame_id: str = frame_id_field("body")


# ----------------------------------------------------------------------------------------------- estimates
class YawEstimate(UavMessage):
    """The yaw of one frame, as published by the master on ``capataz/uav/{uav}/yaw``."""

    seq: int = Field(ge=0, le=MAX_SEQ)  # required
    delta_yaw_rad: float
    yaw_rad: float
    inlier_count: int = Field(ge=0)
    patch_count: int = Field(ge=0)
    confidence: float
    low_confidence: bool
    method: str
    #: stage timings of this frame in milliseconds (``total``, ``dispatch``, ``conclude``, ...).
    timings_ms: dict[str, float] = Field(default_factory=dict)
    #: patches computed by each member for this frame (member name -> count; ``self`` = the master).
    members: dict[str, int] = Field(default_factory=dict)
    #: each member's speed as its dispatcher measured it (patches/s; ``foreman>worker`` for the second tier).
    speeds_patches_s: dict[str, float] = Field(default_factory=dict)
    #: frames of this stream dropped so far by the master's bounded frame queue (oldest first), each once.
    dropped_frames: int = Field(ge=0, default=0)
    #: shares re-dispatched in this frame because a member failed.
    redispatched: int = Field(ge=0, default=0)
    #: how ``delta_yaw_rad`` was obtained: measured by the camera, bridged by the gyro, or the held rate.
    provenance: Provenance = Provenance.MEASURED
    #: variance of ``yaw_rad`` (rad^2) and of this frame's ``delta_yaw_rad``; grows fastest while bridging.
    yaw_variance_rad2: float = Field(ge=0.0, default=0.0)
    delta_variance_rad2: float = Field(ge=0.0, default=0.0)
    #: the camera's own delta when it measured one (also when not trusted), else None.
    measured_delta_rad: float | None = None
    #: yaw is the body's rotation about this frame's z axis (from the stream's first frame)
    frame_id: str = frame_id_field("world")


class AttitudeEstimate(UavMessage):
    """Attitude of the body in the world (Hamilton, scalar first) with its 3x3 error-angle covariance."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "q_world_body": ArraySpec("<f8", (4,)),
        "covariance": ArraySpec("<f8", (3, 3)),
    }
    q_world_body: np.ndarray
    covariance: np.ndarray
    frame_id: str = frame_id_field("world")


class PoseEstimate(UavMessage):
    """Position and attitude of the body in the world with a 6x6 covariance [position, error angles]: of
    ``(dp, dtheta)`` with ``p_true = p_world_body_m + dp`` and ``R_true = Exp(dtheta) R_world_body``, both in
    the world frame and in one sense (the position-rotation correlations change sign otherwise)."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "p_world_body_m": ArraySpec("<f8", (3,)),
        "q_world_body": ArraySpec("<f8", (4,)),
        "covariance": ArraySpec("<f8", (6, 6)),
    }
    p_world_body_m: np.ndarray
    q_world_body: np.ndarray
    covariance: np.ndarray
    #: which estimator produced it, e.g. ``"vo"`` or ``"pf"``.
    source: str
    #: the localizer's tracking state: ``tracking`` (the model matches the image), ``searching`` (a few bad
    #: frames: re-searching around the last good pose), ``lost``; None for estimators without one. A pose
    #: not ``tracking`` is a search's guess, not a measurement: its covariance spans the search about the last
    #: trusted pose (:func:`~common.localization.search.untrusted_covariance`).
    tracking_state: Literal["tracking", "searching", "lost"] | None = None
    frame_id: str = frame_id_field("world")


# ----------------------------------------------------------------------------------------------- service
class ServiceMessage(WireModel):
    """A message about one service instance ``{role}/{node}/{index}`` and how long it has been up."""

    role: str
    node: str
    index: int = Field(ge=0)
    uptime_s: float = Field(ge=0.0)

    @property
    def member(self) -> str:
        """The instance's name, ``role/node/index`` (the key of the member in every report)."""
        return f"{self.role}/{self.node}/{self.index}"


class Stats(ServiceMessage):
    """Periodic statistics of a service (``capataz/stats/{role}/{node}/{i}``)."""

    stamp_s: float
    counters: dict[str, int] = Field(default_factory=dict)
    timings_ms: dict[str, float] = Field(default_factory=dict)
    queue_depths: dict[str, int] = Field(default_factory=dict)
    shares: dict[str, float] = Field(default_factory=dict)
    #: CPU seconds (user + system, every thread) the member's process used since it started
    #: (``time.process_time``): a role's CPU per frame is its growth over the frames of a window
    cpu_s: float = Field(ge=0.0, default=0.0)
    #: the machine the member runs on (its host name: a container's in compose), "" when unknown
    host: str = Field(default="", max_length=255)
    #: the UAV streams the member serves (a master's, an estimator's; a camera's several), empty for
    #: members of every stream (workers, foremen, the router)
    uavs: list[Uav] = Field(default_factory=list, max_length=64)


class Health(ServiceMessage):
    """Answer of a service's health queryable."""

    ok: bool
    detail: str = ""
    counters: dict[str, int] = Field(default_factory=dict)


class ErrorReply(WireModel):
    """Body of an error reply to a query (travels as the header alone)."""

    kind: str
    error: str
