"""Rig files -> :class:`common.rig.Rig`, and the capataz rig file back out.

Formats, detected from the text (the camera part is read by :mod:`common.datasets.calibration`):

- **capataz rig YAML** (what :func:`write_rig` writes): an OpenCV YAML calibration (``%YAML``,
  ``!!opencv-matrix``) with the optional mount keys ``R_body_camera`` (3x3), ``t_body_camera_m`` (3x1),
  ``R_body_imu`` (3x3) and ``time_offset_s`` (s, ``t_imu = t_cam + time_offset_s``). Without them (a plain
  OpenCV calibration) the mount is :class:`Rig`'s default: a down camera, the IMU as the body.
- **ROS camera_info YAML** (or a ``sensor_msgs/CameraInfo`` mapping): the camera only, the default mount.
- **EuRoC** ``sensor.yaml`` (Burri et al., IJRR 2016): ``intrinsics: [fu, fv, cu, cv]``,
  ``distortion_model`` (``radial-tangential`` / ``equidistant``), ``distortion_coefficients``,
  ``resolution: [width, height]`` and ``T_BS: {rows: 4, cols: 4, data}``, the sensor's pose in the body
  frame (body-from-sensor; EuRoC's body is its IMU): ``R_body_camera`` and ``t_body_camera_m`` as given,
  ``R_body_imu`` the identity.
- **Kalibr** ``camchain.yaml`` / ``camchain-imucam.yaml`` (https://github.com/ethz-asl/kalibr/wiki/yaml-formats):
  ``cam0``'s ``camera_model`` (``pinhole`` only), ``intrinsics: [fu, fv, pu, pv]``, ``distortion_model``
  (``radtan`` / ``equidistant``), ``distortion_coeffs``, ``resolution``, ``T_cam_imu`` (IMU-to-camera,
  ``T_c_i``: inverted here, the IMU is the body) and ``timeshift_cam_imu`` (``t_imu = t_cam + shift``: taken
  as ``time_offset_s`` unchanged). Without ``T_cam_imu`` (a camera-only chain): the default mount.

Every problem is one :class:`RigFileError` naming the file and what is wrong.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.camera import CameraModel
from common.datasets.calibration import (
    MAX_CALIBRATION_BYTES,
    CalibrationError,
    camera_from_camera_info,
    camera_from_mapping,
    float_list,
    int_value,
    matrix_data,
    opencv_matrix,
    opencv_yaml_text,
    parse_calibration,
    yaml_mapping,
)
from common.datasets.files import read_text_file
from common.errors import InputError
from common.rig import Rig
from common.types import FloatArray

#: the mount keys of the capataz rig YAML, with the shape each must have.
MOUNT_KEYS: dict[str, tuple[int, ...]] = {
    "R_body_camera": (3, 3),
    "t_body_camera_m": (3,),
    "R_body_imu": (3, 3),
}
_TIME_OFFSET_KEY = "time_offset_s"
#: a top-level key only a EuRoC sensor.yaml or a Kalibr camchain has (both may start with ``%YAML`` too)
_EUROC_OR_KALIBR = re.compile(r"^(intrinsics|cam0)\s*:", re.MULTILINE)


class RigFileError(CalibrationError):
    """A rig file could not be read as a rig (the text names the file and what is wrong)."""


def load_rig(path: str | os.PathLike[str]) -> Rig:
    """The rig described by the file at ``path`` (format detected: see the module docstring)."""
    p = Path(path)
    text = read_text_file(p, MAX_CALIBRATION_BYTES, "rig file", RigFileError)
    try:
        return parse_rig(text)
    except InputError as exc:
        raise RigFileError(f"rig file {p}: {exc}") from None


def parse_rig(text: str) -> Rig:
    """The rig described by a rig file's text (InputError naming what is wrong, not the file)."""
    if "!!opencv-matrix" in text or (text.lstrip().startswith("%YAML") and not _EUROC_OR_KALIBR.search(text)):
        return Rig(parse_calibration(text), **_opencv_mount(text))
    lines = text.splitlines()
    if lines and lines[0].startswith("%YAML"):  # EuRoC's ``%YAML:1.0`` is not YAML 1.1 PyYAML reads
        text = "\n".join(lines[1:])
    data = yaml_mapping(text, "rig file")
    if isinstance(data.get("cam0"), Mapping):
        return _kalibr(data["cam0"])
    if "intrinsics" in data:
        return _euroc(data)
    if "camera_matrix" in data or ("k" in {str(k).lower() for k in data} and "width" in data):
        return Rig(camera_from_mapping(data))
    raise RigFileError(
        "not a rig file: expected an OpenCV YAML calibration, a ROS camera_info (camera_matrix), a EuRoC "
        f"sensor.yaml (intrinsics, T_BS) or a Kalibr camchain (cam0); found keys {sorted(map(str, data))[:8]}"
    )


def rig_yaml_text(rig: Rig) -> str:
    """The capataz rig YAML of ``rig``: its camera as an OpenCV YAML calibration, then the mount keys
    (17 significant digits: :func:`parse_rig` reads back an equal rig)."""
    fs = cv2.FileStorage("rig.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("R_body_camera", np.asarray(rig.R_body_camera, dtype=np.float64))
    fs.write("t_body_camera_m", np.asarray(rig.t_body_camera_m, dtype=np.float64).reshape(3, 1))
    fs.write("R_body_imu", np.asarray(rig.R_body_imu, dtype=np.float64))
    fs.write(_TIME_OFFSET_KEY, float(rig.time_offset_s))
    mount = str(fs.releaseAndGetString()).split("---\n", 1)[1]
    return opencv_yaml_text(rig.camera) + mount


def write_rig(rig: Rig, path: str | os.PathLike[str]) -> Path:
    """Write ``rig`` to ``path`` as the capataz rig YAML (:func:`rig_yaml_text`); returns the path."""
    p = Path(path)
    p.write_text(rig_yaml_text(rig))
    return p


def _opencv_mount(text: str) -> dict[str, Any]:
    """The mount keys present in an OpenCV YAML text (checked by :class:`Rig`)."""
    fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    try:
        mount: dict[str, Any] = {}
        for name, shape in MOUNT_KEYS.items():
            mat = opencv_matrix(fs, (name,))
            if mat is not None:
                if mat.size != int(np.prod(shape)) or (len(shape) == 2 and mat.shape != shape):
                    raise RigFileError(f"{name} must be {'x'.join(map(str, shape))}, got {mat.shape}")
                mount[name] = mat.reshape(shape)
        node = fs.getNode(_TIME_OFFSET_KEY)
        if not node.empty():
            if not node.isReal() and not node.isInt():
                raise RigFileError(f"{_TIME_OFFSET_KEY} is not a number")
            mount["time_offset_s"] = float(node.real())
    finally:
        fs.release()
    return mount


def _pinhole_camera(doc: Mapping[str, Any], coeffs_key: str, what: str) -> CameraModel:
    """The camera of a EuRoC / Kalibr camera mapping (``intrinsics``, ``resolution``, the lens)."""
    intrinsics = float_list(_required(doc, "intrinsics", what), "intrinsics")
    if len(intrinsics) != 4:
        raise RigFileError(f"{what}: intrinsics must be [fu, fv, cu, cv], got {len(intrinsics)} values")
    resolution = _required(doc, "resolution", what)
    if not isinstance(resolution, list) or len(resolution) != 2:
        raise RigFileError(f"{what}: resolution must be [width, height], got {resolution!r}")
    width = int_value({"resolution width": resolution[0]}, "resolution width")
    height = int_value({"resolution height": resolution[1]}, "resolution height")
    fu, fv, cu, cv = intrinsics
    coeffs = float_list(doc.get(coeffs_key, []), coeffs_key)
    model = doc.get("distortion_model", "radtan")
    if not isinstance(model, str):
        raise RigFileError(f"{what}: distortion_model must be a name, got {model!r}")
    return camera_from_camera_info(width, height, model, coeffs, [fu, 0.0, cu, 0.0, fv, cv, 0.0, 0.0, 1.0])


def _euroc(doc: Mapping[str, Any]) -> Rig:
    camera = _pinhole_camera(doc, "distortion_coefficients", "EuRoC sensor.yaml")
    T_body_camera = _transform(matrix_data(_required(doc, "T_BS", "EuRoC sensor.yaml"), "T_BS"), "T_BS")
    return Rig(camera, R_body_camera=T_body_camera[:3, :3], t_body_camera_m=T_body_camera[:3, 3])


def _kalibr(cam: Mapping[str, Any]) -> Rig:
    model = cam.get("camera_model", "pinhole")
    if model != "pinhole":
        raise RigFileError(f"Kalibr cam0: camera_model {model!r} is not supported (pinhole only)")
    camera = _pinhole_camera(cam, "distortion_coeffs", "Kalibr cam0")
    if "T_cam_imu" not in cam:
        return Rig(camera)
    rows = cam["T_cam_imu"]
    if not isinstance(rows, list) or not all(isinstance(r, list) for r in rows):
        raise RigFileError(f"T_cam_imu must be a list of 4 rows, got {type(rows).__name__}")
    T_cam_imu = _transform([v for row in rows for v in float_list(row, "T_cam_imu")], "T_cam_imu")
    R_cam_imu, t_cam_imu = T_cam_imu[:3, :3], T_cam_imu[:3, 3]
    offset = cam.get("timeshift_cam_imu", 0.0)
    if isinstance(offset, bool) or not isinstance(offset, int | float):
        raise RigFileError(f"timeshift_cam_imu must be a number, got {offset!r}")
    # the IMU is the body: T_body_camera = T_imu_cam = T_cam_imu^-1
    return Rig(
        camera, R_body_camera=R_cam_imu.T, t_body_camera_m=-R_cam_imu.T @ t_cam_imu, time_offset_s=offset
    )


def _transform(values: list[float], name: str) -> FloatArray:
    """A 4x4 rigid transform from its 16 row-major values (its rotation is checked by :class:`Rig`)."""
    if len(values) != 16:
        raise RigFileError(f"{name} must be 4x4 (16 values), got {len(values)}")
    T = np.asarray(values, dtype=np.float64).reshape(4, 4)
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
        raise RigFileError(f"{name}'s last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    return T


def _required(doc: Mapping[str, Any], key: str, what: str) -> Any:
    if key not in doc:
        raise RigFileError(f"{what}: missing {key}")
    return doc[key]
