"""The wire message of a stream's camera rig (:class:`common.rig.Rig`) and its converters.

The camera publishes its stream's :class:`RigMessage` on ``capataz/uav/{uav}/rig``
(:func:`common.wire.keys.rig_key`) and stamps each :class:`~common.wire.messages.Frame` with its
``rig_id``, so a service notices a changed rig. A message is checked once, at decode: every field bounded,
the rig it describes valid (:class:`Rig`'s checks: rotations, lens invertible over the image) and its
``rig_id`` the id of that content; anything else is a :class:`~common.wire.schema.WireError`.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import ConfigDict, Field, PrivateAttr, model_validator

from common.camera import CameraModel, Distortion, DistortionModel
from common.errors import InputError
from common.rig import MAX_TIME_OFFSET_S, Rig
from common.wire.messages import UavMessage
from common.wire.schema import MAX_FRAME_SIDE_PX, RIG_ID_PATTERN, ArraySpec, WireModel, frame_id_field

#: the most lens coefficients a rig carries (radtan's k1 k2 p1 p2 k3).
MAX_LENS_COEFFS = 5
#: a principal point lies within this many frame sides of the image (a calibration's, not a typo's).
_MAX_PRINCIPAL_PX = 2.0 * MAX_FRAME_SIDE_PX
#: a focal length in pixels (a 8192 px wide image at 0.01 deg of field of view is 4.7e7 px).
_MAX_FOCAL_PX = 1e8


class RigMessage(UavMessage):
    """A UAV stream's camera rig: the camera model, the mount, the camera-IMU time offset and its id.

    ``stamp_s`` is the stamp of the stream's first frame the rig applies to; ``frame_id`` is the body.
    """

    model_config = ConfigDict(**WireModel.model_config, strict=True)
    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "distortion_coeffs": ArraySpec("<f8", (None,)),
        "R_body_camera": ArraySpec("<f8", (3, 3)),
        "t_body_camera_m": ArraySpec("<f8", (3,)),
        "R_body_imu": ArraySpec("<f8", (3, 3)),
    }
    rig_id: str = Field(pattern=RIG_ID_PATTERN)
    width: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    height: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    fx: float = Field(gt=0.0, le=_MAX_FOCAL_PX)
    fy: float = Field(gt=0.0, le=_MAX_FOCAL_PX)
    cx: float = Field(ge=-_MAX_PRINCIPAL_PX, le=_MAX_PRINCIPAL_PX)
    cy: float = Field(ge=-_MAX_PRINCIPAL_PX, le=_MAX_PRINCIPAL_PX)
    distortion_model: Literal["none", "radtan", "fisheye"]
    distortion_coeffs: np.ndarray
    R_body_camera: np.ndarray
    t_body_camera_m: np.ndarray
    R_body_imu: np.ndarray
    #: camera clock to IMU clock (s): ``t_imu = t_cam + time_offset_s`` (:mod:`common.rig`).
    time_offset_s: float = Field(ge=-MAX_TIME_OFFSET_S, le=MAX_TIME_OFFSET_S)
    frame_id: str = frame_id_field("body")
    _rig: Rig = PrivateAttr()

    @model_validator(mode="after")
    def _a_rig_with_its_id(self) -> RigMessage:
        if self.distortion_coeffs.shape[0] > MAX_LENS_COEFFS:
            raise ValueError(f"distortion_coeffs: {self.distortion_coeffs.shape[0]} > {MAX_LENS_COEFFS}")
        try:
            lens = Distortion(DistortionModel(self.distortion_model), tuple(self.distortion_coeffs.tolist()))
            camera = CameraModel(self.width, self.height, self.fx, self.fy, self.cx, self.cy, lens)
            rig = Rig(
                camera,
                R_body_camera=self.R_body_camera,
                t_body_camera_m=self.t_body_camera_m,
                R_body_imu=self.R_body_imu,
                time_offset_s=self.time_offset_s,
            )
        except InputError as exc:
            raise ValueError(f"not a rig: {exc}") from None
        if rig.rig_id != self.rig_id:
            raise ValueError(f"rig_id {self.rig_id} is not its content's id {rig.rig_id}")
        self._rig = rig
        return self


def message_of_rig(uav: str, rig: Rig, stamp_s: float, seq: int = 0) -> RigMessage:
    """The wire message of ``uav``'s rig (its id computed from its content)."""
    cam = rig.camera
    return RigMessage(
        uav=uav,
        seq=seq,
        stamp_s=float(stamp_s),
        rig_id=rig.rig_id,
        width=int(cam.width),
        height=int(cam.height),
        fx=float(cam.fx),
        fy=float(cam.fy),
        cx=float(cam.cx),
        cy=float(cam.cy),
        distortion_model=cam.distortion.model.value,
        distortion_coeffs=np.asarray(cam.distortion.coeffs, dtype=np.float64),
        R_body_camera=np.array(rig.R_body_camera),
        t_body_camera_m=np.array(rig.t_body_camera_m),
        R_body_imu=np.array(rig.R_body_imu),
        time_offset_s=float(rig.time_offset_s),
    )


def rig_from_message(message: RigMessage) -> Rig:
    """The rig a (validated) :class:`RigMessage` carries; its ``rig_id`` is the message's."""
    return message._rig
