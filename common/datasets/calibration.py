"""Camera calibration texts -> :class:`common.camera.CameraModel` (files are read by
:func:`common.datasets.rig_files.load_rig`, the one reader of every camera and rig file).

Two formats, detected from the text:

- **OpenCV YAML** (what ``cv2.FileStorage`` writes, e.g. OpenCV's calibration sample): ``%YAML:1.0`` with
  ``!!opencv-matrix`` nodes. Keys: ``camera_matrix`` (or ``K`` / ``cameraMatrix``),
  ``distortion_coefficients`` (or ``D`` / ``dist_coeffs`` / ``distCoeffs``), ``image_width`` /
  ``image_height`` (or ``width`` / ``height``), optional ``distortion_model`` (``radtan``, the default, or
  ``fisheye``).
- **ROS camera_info YAML** (``camera_calibration_parsers``, what ``cameracalibrator`` saves): ``image_width``,
  ``image_height``, ``camera_matrix: {rows, cols, data}``, ``distortion_model`` (``plumb_bob`` or
  ``equidistant``), ``distortion_coefficients: {rows, cols, data}``. A ``sensor_msgs/CameraInfo`` message as a
  mapping (``width``, ``height``, ``distortion_model``, ``d``, ``k``) is accepted too.

Every problem is one :class:`CalibrationError` saying what is wrong.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
import yaml

from common.camera import CameraModel, Distortion, DistortionModel
from common.errors import InputError

#: the largest calibration file read (a calibration is a few hundred bytes; anything larger is not one).
MAX_CALIBRATION_BYTES = 1 << 20

_DISTORTION_NAMES = {
    "": DistortionModel.NONE,
    "none": DistortionModel.NONE,
    "pinhole": DistortionModel.NONE,
    "plumb_bob": DistortionModel.RADTAN,
    "radtan": DistortionModel.RADTAN,
    "radial-tangential": DistortionModel.RADTAN,
    "equidistant": DistortionModel.FISHEYE,
    "fisheye": DistortionModel.FISHEYE,
    "kannala_brandt": DistortionModel.FISHEYE,
}


class CalibrationError(InputError):
    """A calibration file or mapping could not be read as a camera."""


def parse_calibration(text: str) -> CameraModel:
    """The camera described by a calibration's text (format detected: OpenCV YAML or ROS camera_info YAML)."""
    if text.lstrip().startswith("%YAML") or "!!opencv-matrix" in text:
        return _parse_opencv_yaml(text)
    return camera_from_mapping(yaml_mapping(text, "calibration"))


def yaml_mapping(text: str, what: str) -> Mapping[str, Any]:
    """The YAML mapping of ``text``; not YAML (its problem and line, on one line) or not a mapping raises
    CalibrationError saying it is not a ``what``."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise CalibrationError(f"not YAML{where}: {problem}") from None
    if not isinstance(data, Mapping):
        raise CalibrationError(f"not a {what}: the YAML document is not a mapping")
    return data


def camera_from_mapping(data: Mapping[str, Any]) -> CameraModel:
    """The camera of a ROS camera_info YAML document or a ``sensor_msgs/CameraInfo`` message as a mapping."""
    if "camera_matrix" in data:
        return camera_from_camera_info(
            width=int_value(data, "image_width"),
            height=int_value(data, "image_height"),
            distortion_model=str(data.get("distortion_model", "plumb_bob")),
            d=matrix_data(data.get("distortion_coefficients", {"data": []}), "distortion_coefficients"),
            k=matrix_data(data["camera_matrix"], "camera_matrix"),
        )
    keys = {str(k).lower(): k for k in data}
    if "k" in keys and "width" in keys:
        return camera_from_camera_info(
            width=int_value(data, keys["width"]),
            height=int_value(data, keys["height"]) if "height" in keys else _missing("height"),
            distortion_model=str(data.get(keys.get("distortion_model", ""), "plumb_bob")),
            d=float_list(data.get(keys.get("d", ""), []), "d"),
            k=float_list(data[keys["k"]], "k"),
        )
    raise CalibrationError(
        "not a calibration: expected camera_matrix (ROS camera_info YAML) or K and width (CameraInfo), "
        f"found keys {sorted(map(str, data))[:8]}"
    )


def camera_from_camera_info(
    width: int, height: int, distortion_model: str, d: Sequence[float], k: Sequence[float]
) -> CameraModel:
    """The camera of a ``sensor_msgs/CameraInfo``: size, distortion model name, D and the row-major 3x3 K."""
    name = distortion_model.strip().lower()
    if name not in _DISTORTION_NAMES:
        raise CalibrationError(
            f"distortion model {distortion_model!r} is not supported (supported: plumb_bob/radtan, "
            "equidistant/fisheye, none)"
        )
    model = _DISTORTION_NAMES[name]
    coeffs = [float(c) for c in d]
    if model is DistortionModel.RADTAN and len(coeffs) > 5:
        if any(coeffs[5:]):
            raise CalibrationError(f"{len(coeffs)} radtan coefficients: only k1 k2 p1 p2 k3 are supported")
        coeffs = coeffs[:5]
    if model is DistortionModel.RADTAN and not any(coeffs):
        # radtan with zero coefficients is a pinhole; a fisheye with zero coefficients is not (the ideal
        # equidistant lens, r = f theta) and stays a fisheye
        model, coeffs = DistortionModel.NONE, []
    if len(k) != 9:
        raise CalibrationError(f"camera matrix must have 9 values, got {len(k)}")
    try:
        return CameraModel.from_K(
            np.asarray(k, dtype=np.float64).reshape(3, 3), width, height, Distortion(model, tuple(coeffs))
        )
    except CalibrationError:
        raise
    except InputError as exc:
        raise CalibrationError(str(exc)) from None


def opencv_yaml_text(camera: CameraModel) -> str:
    """The camera as an OpenCV YAML calibration (what :func:`parse_calibration` reads back exactly)."""
    fs = cv2.FileStorage("calibration.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    fs.write("camera_matrix", camera.K)
    fs.write("distortion_model", camera.distortion.model.value)
    coeffs = camera.distortion.coeffs or (0.0,) * 5
    fs.write("distortion_coefficients", np.asarray(coeffs, dtype=np.float64).reshape(1, -1))
    return str(fs.releaseAndGetString())


def ros_yaml_text(camera: CameraModel, camera_name: str = "camera") -> str:
    """The camera as a ROS camera_info YAML calibration."""
    ros_name = {
        DistortionModel.NONE: "plumb_bob",
        DistortionModel.RADTAN: "plumb_bob",
        DistortionModel.FISHEYE: "equidistant",
    }[camera.distortion.model]
    d = list(camera.distortion.coeffs) or [0.0] * 5
    P = np.hstack([camera.K, np.zeros((3, 1))])
    doc = {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "camera_name": camera_name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in camera.K.ravel()]},
        "distortion_model": ros_name,
        "distortion_coefficients": {"rows": 1, "cols": len(d), "data": [float(v) for v in d]},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in np.eye(3).ravel()]},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in P.ravel()]},
    }
    return str(yaml.safe_dump(doc, sort_keys=False))


def _parse_opencv_yaml(text: str) -> CameraModel:
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # OpenCV's parser raises SystemError on some syntax errors
        lines = str(exc).strip().splitlines()
        raise CalibrationError(f"not an OpenCV YAML file ({lines[-1] if lines else 'unreadable'})") from None
    try:
        K = opencv_matrix(fs, ("camera_matrix", "K", "cameraMatrix"))
        if K is None:
            raise CalibrationError("OpenCV YAML without camera_matrix (or K / cameraMatrix)")
        D = opencv_matrix(fs, ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs"))
        width = _first_int(fs, ("image_width", "width"))
        height = _first_int(fs, ("image_height", "height"))
        model_node = fs.getNode("distortion_model")
        model = model_node.string() if not model_node.empty() and model_node.isString() else "radtan"
    finally:
        fs.release()
    if width is None or height is None:
        raise CalibrationError("OpenCV YAML without image_width and image_height")
    d = [] if D is None else [float(v) for v in np.asarray(D, dtype=np.float64).ravel()]
    return camera_from_camera_info(width, height, model or "radtan", d, [float(v) for v in K.ravel()])


def opencv_matrix(fs: cv2.FileStorage, names: tuple[str, ...]) -> np.ndarray | None:
    """The first of the ``!!opencv-matrix`` nodes ``names`` present in ``fs`` as float64, None if none is."""
    for name in names:
        node = fs.getNode(name)
        if not node.empty():
            try:
                mat = node.mat()
            except cv2.error:  # its data does not fill rows x cols (OpenCV's bare assertion otherwise)
                rows, cols = node.getNode("rows").real(), node.getNode("cols").real()
                n = node.getNode("data").size()
                raise CalibrationError(f"{name} says {rows:g}x{cols:g} but has {n} values") from None
            if mat is None:
                raise CalibrationError(f"{name} is not a matrix")
            return np.asarray(mat, dtype=np.float64)
    return None


def _first_int(fs: cv2.FileStorage, names: tuple[str, ...]) -> int | None:
    for name in names:
        node = fs.getNode(name)
        if not node.empty():
            if not node.isInt():
                raise CalibrationError(f"{name} is not an integer")
            return int(node.real())
    return None


def _missing(name: str) -> int:
    raise CalibrationError(f"missing {name}")


def int_value(data: Mapping[str, Any], key: str) -> int:
    """``data[key]``, which must be present and an integer (not a bool)."""
    if key not in data:
        raise CalibrationError(f"missing {key}")
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise CalibrationError(f"{key} must be an integer, got {value!r}")
    return value


def float_list(values: Any, name: str) -> list[float]:
    """``values`` as a list of finite floats (a YAML sequence of numbers)."""
    if not isinstance(values, Sequence) or isinstance(values, str | bytes):
        raise CalibrationError(f"{name} must be a list of numbers, got {type(values).__name__}")
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be a list of numbers") from None
    if not all(np.isfinite(out)):
        raise CalibrationError(f"{name} must be finite")
    return out


def matrix_data(node: Any, name: str) -> list[float]:
    """The ``data`` of a ``{rows, cols, data}`` mapping (ROS, EuRoC), checked against rows x cols."""
    if not isinstance(node, Mapping) or "data" not in node:
        raise CalibrationError(f"{name} must be a mapping with rows, cols and data")
    data = float_list(node["data"], f"{name}.data")
    rows, cols = node.get("rows"), node.get("cols")
    if rows is not None and cols is not None and rows * cols != len(data):
        raise CalibrationError(f"{name} says {rows}x{cols} but has {len(data)} values")
    return data
