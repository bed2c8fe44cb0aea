"""The camera rig of one UAV stream: its one camera model, how the camera and the IMU sit on the body, and
the camera-IMU time offset (a pure value; its files: :mod:`common.datasets.rig_files`, its wire message:
:mod:`common.wire.rig`).

Frames and conventions (:mod:`common.geometry`): ``R_body_camera`` rotates camera-frame vectors (OpenCV:
x right, y down, z along the optical axis) into the body frame, ``t_body_camera_m`` is the camera's optical
centre in the body frame (metres), ``R_body_imu`` rotates IMU-frame vectors (what the gyro and the
accelerometer measure) into the body frame. A rig read from EuRoC or Kalibr takes the IMU as the body
(``R_body_imu`` = identity).

Clocks: ``time_offset_s`` maps the camera's clock to the IMU's, ``t_imu = t_cam + time_offset_s``: the sign of
Kalibr's ``timeshift_cam_imu`` ("timeshift between camera and IMU timestamps in seconds (t_imu = t_cam +
shift)", https://github.com/ethz-asl/kalibr/wiki/yaml-formats), so Kalibr's value is taken unchanged. An image
stamped ``t_cam`` was taken when the IMU's clock read ``t_cam + time_offset_s``.

Identity: :attr:`Rig.rig_id` is the first 16 hex digits of the SHA-256 of a canonical text of every field,
each real number rounded to :data:`RIG_ID_DECIMALS` decimals (1e-9 px, 1e-9 of a rotation entry, 1 nm,
1 ns): two rigs that differ by less than that in every field may share an id; rigs that differ by more than
it in any field do not (up to hash collisions). The id travels in each frame's header so a changed rig is
noticed.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel, DistortionModel
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, check_rotation_matrix, constant
from common.types import FloatArray

#: every real number of a rig is rounded to this many decimals before it is hashed into :attr:`Rig.rig_id`.
RIG_ID_DECIMALS = 9
#: hex digits of :attr:`Rig.rig_id` (64 bits of SHA-256).
RIG_ID_HEX = 16
#: the largest camera-IMU time offset accepted (s): calibrated offsets are milliseconds; more is a unit error.
MAX_TIME_OFFSET_S = 1.0
#: the largest camera lever arm accepted (m): a UAV's camera sits within metres of its IMU.
MAX_LEVER_ARM_M = 100.0
#: the tag of the canonical encoding (a change of the encoding changes every id).
_ID_VERSION = "capataz-rig-1"


def _frozen(values: npt.ArrayLike, shape: tuple[int, ...], name: str) -> FloatArray:
    try:
        arr = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be numbers, got {values!r}") from None
    if arr.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite")
    return constant(arr)


@dataclass(frozen=True, eq=False)
class Rig:
    """One camera on a body with an IMU (see the module docstring for frames, clocks and the id)."""

    camera: CameraModel
    R_body_camera: FloatArray = field(default_factory=lambda: R_BODY_CAMERA_DOWN)
    t_body_camera_m: FloatArray = field(default_factory=lambda: constant(np.zeros(3)))
    R_body_imu: FloatArray = field(default_factory=lambda: constant(np.eye(3)))
    time_offset_s: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.camera, CameraModel):
            raise InputError(f"camera must be a CameraModel, got {type(self.camera).__name__}")
        if self.camera.distortion.model is not DistortionModel.NONE and self.camera.distortion.is_identity:
            # radtan with all-zero coefficients is the pinhole it is (as the calibration readers read it):
            # one lens, one id
            object.__setattr__(self, "camera", self.camera.pinhole())
        for name in ("R_body_camera", "R_body_imu"):
            R = _frozen(getattr(self, name), (3, 3), name)
            check_rotation_matrix(R, name)
            object.__setattr__(self, name, R)
        t = _frozen(self.t_body_camera_m, (3,), "t_body_camera_m")
        if float(np.linalg.norm(t)) > MAX_LEVER_ARM_M:
            raise InputError(f"t_body_camera_m: {np.linalg.norm(t):.3g} m is over {MAX_LEVER_ARM_M} m")
        object.__setattr__(self, "t_body_camera_m", t)
        offset = self.time_offset_s
        if (
            isinstance(offset, bool)
            or not isinstance(offset, int | float | np.floating)
            or not np.isfinite(offset)
        ):
            raise InputError(f"time_offset_s must be a finite number, got {offset!r}")
        if abs(offset) > MAX_TIME_OFFSET_S:
            raise InputError(f"time_offset_s: |{offset}| s is over {MAX_TIME_OFFSET_S} s")
        object.__setattr__(self, "time_offset_s", float(offset))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Rig):
            return NotImplemented
        return (
            self.camera == other.camera
            and np.array_equal(self.R_body_camera, other.R_body_camera)
            and np.array_equal(self.t_body_camera_m, other.t_body_camera_m)
            and np.array_equal(self.R_body_imu, other.R_body_imu)
            and self.time_offset_s == other.time_offset_s
        )

    def __hash__(self) -> int:
        return hash(self.rig_id)

    @property
    def R_camera_imu(self) -> FloatArray:
        """Rotates IMU-frame vectors into the camera frame (``R_body_camera^T R_body_imu``)."""
        return np.asarray(self.R_body_camera.T @ self.R_body_imu, dtype=np.float64)

    @cached_property
    def rig_id(self) -> str:
        """First :data:`RIG_ID_HEX` hex digits of the SHA-256 of :meth:`canonical_text`."""
        return hashlib.sha256(self.canonical_text().encode("ascii")).hexdigest()[:RIG_ID_HEX]

    def canonical_text(self) -> str:
        """The text the id hashes: every field, reals as integers of ``10**-RIG_ID_DECIMALS`` units."""
        cam = self.camera
        doc: dict[str, Any] = {
            "v": _ID_VERSION,
            "size": [int(cam.width), int(cam.height)],
            "K": _quanta([cam.fx, cam.fy, cam.cx, cam.cy]),
            "lens": cam.distortion.model.value,
            "coeffs": _quanta(cam.distortion.coeffs),
            "R_body_camera": _quanta(self.R_body_camera.ravel()),
            "t_body_camera_m": _quanta(self.t_body_camera_m),
            "R_body_imu": _quanta(self.R_body_imu.ravel()),
            "time_offset_s": _quanta([self.time_offset_s]),
        }
        return json.dumps(doc, sort_keys=True, separators=(",", ":"))


def _quanta(values: npt.ArrayLike) -> list[int]:
    """Each value as an integer count of ``10**-RIG_ID_DECIMALS`` (exact, no sign of zero)."""
    scale = 10.0**RIG_ID_DECIMALS
    return [round(float(v) * scale) for v in np.asarray(values, dtype=np.float64).ravel()]
