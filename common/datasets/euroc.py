"""EuRoC MAV folders (the ASL format): ``mav0/cam0/data.csv`` + ``data/*.png``, ``mav0/imu0/data.csv``,
``mav0/state_groundtruth_estimate0/data.csv`` and the camera's ``sensor.yaml``.

Stamps are nanoseconds in the files and seconds here. A rangefinder is not part of EuRoC; capataz reads
an optional ``mav0/range0/data.csv`` (``#timestamp [ns],range [m]``) in the same layout, which is how its
tests store a simulated flight's rangefinder. IMU samples are passed through in the IMU's own frame.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from common.camera import CameraModel
from common.datasets.calibration import CalibrationError, camera_from_camera_info
from common.datasets.images import ImageFolder, ImageFolderError, open_image_folder
from common.datasets.tum import Trajectory, TumError
from common.errors import InputError
from common.estimation.measurements import (
    SENSOR_ORDER,
    FrameMeasurement,
    ImuMeasurement,
    Measurement,
    RangeMeasurement,
    sensor_of,
)
from common.rig import Rig


class EurocError(InputError):
    """A EuRoC folder is missing a part or holds a malformed file."""


@dataclass(frozen=True)
class EurocFolder:
    """An opened EuRoC folder: the camera's images (checked), IMU and range tables, ground truth."""

    root: Path
    camera: ImageFolder
    imu: np.ndarray  # (N, 7): stamp_s, gyro xyz rad/s, accel xyz m/s^2
    range: np.ndarray  # (M, 2): stamp_s, range_m
    camera_info: CameraModel | None
    ground_truth: Trajectory | None

    def measurements(self) -> Iterator[Measurement]:
        """Frames, IMU and range samples merged in stamp order (equal stamps in
        :data:`~common.estimation.measurements.SENSOR_ORDER`: range, IMU, frame)."""
        imu: Iterator[Measurement] = (
            ImuMeasurement(float(r[0]), r[1:4].copy(), r[4:7].copy()) for r in self.imu
        )
        rng: Iterator[Measurement] = (RangeMeasurement(float(r[0]), float(r[1])) for r in self.range)
        frames: Iterator[Measurement] = iter(self.camera.frames())
        yield from heapq.merge(imu, rng, frames, key=lambda m: (m.stamp_s, SENSOR_ORDER[sensor_of(m)]))


def _table(path: Path, columns: int, what: str) -> np.ndarray:
    """A EuRoC csv (first column ns) as float rows with the stamp in seconds; EurocError if malformed."""
    try:
        rows = [
            line.split(",")
            for line in path.read_text().splitlines()
            if line.strip() and not line.startswith("#")
        ]
        data = np.array([[float(v) for v in row] for row in rows], dtype=np.float64).reshape(
            -1, len(rows[0]) if rows else columns
        )
        stamps_ns = np.array([int(row[0]) for row in rows], dtype=np.int64)
    except (OSError, UnicodeDecodeError) as exc:
        raise EurocError(f"{what} {path}: cannot be read ({exc})") from None
    except ValueError as exc:
        raise EurocError(f"{what} {path}: malformed ({exc})") from None
    if data.shape[1] < columns:
        raise EurocError(f"{what} {path}: expected at least {columns} columns, got {data.shape[1]}")
    if not np.all(np.isfinite(data)):
        raise EurocError(f"{what} {path}: NaN or inf")
    data[:, 0] = stamps_ns / 1e9
    if np.any(np.diff(data[:, 0]) <= 0):
        raise EurocError(f"{what} {path}: stamps must increase")
    return data


def _camera_info(path: Path, width: int, height: int) -> CameraModel | None:
    """The camera of EuRoC's ``sensor.yaml`` (``intrinsics: [fu, fv, cu, cv]``, ``distortion_model``,
    ``distortion_coefficients``, ``resolution``), or None without the file."""
    if not path.is_file():
        return None
    try:
        text = "\n".join(line for line in path.read_text().splitlines() if not line.startswith("%YAML"))
        doc = yaml.safe_load(text)
        fx, fy, cx, cy = (float(v) for v in doc["intrinsics"])
        coeffs = [float(v) for v in doc.get("distortion_coefficients", ())]
        w, h = (int(v) for v in doc.get("resolution", (width, height)))
        model = str(doc.get("distortion_model", "radial-tangential"))
        camera = camera_from_camera_info(w, h, model, coeffs, [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise EurocError(f"camera calibration {path}: malformed ({type(exc).__name__}: {exc})") from None
    except CalibrationError as exc:
        raise EurocError(f"camera calibration {path}: {exc}") from None
    if (camera.width, camera.height) != (width, height):
        raise EurocError(f"camera calibration {path}: {w}x{h}, but the images are {width}x{height}")
    return camera


def open_euroc(folder: Path) -> EurocFolder:
    """Open and check a EuRoC folder (``DIR`` holding ``mav0/``, or ``mav0`` itself)."""
    root = Path(folder)
    if not root.is_dir():
        raise EurocError(f"{root}: not a folder")
    mav = root / "mav0" if (root / "mav0").is_dir() else root
    cam = mav / "cam0"
    if not (cam / "data.csv").is_file() or not (cam / "data").is_dir():
        raise EurocError(f"{root}: not a EuRoC folder (no mav0/cam0/data.csv and mav0/cam0/data/)")
    try:
        camera = open_image_folder(cam / "data", stamps_file=cam / "data.csv")
    except ImageFolderError as exc:
        raise EurocError(f"cam0: {exc}") from None
    imu_csv = mav / "imu0" / "data.csv"
    imu = _table(imu_csv, 7, "imu0") if imu_csv.is_file() else np.zeros((0, 7))
    range_csv = mav / "range0" / "data.csv"
    rng = _table(range_csv, 2, "range0") if range_csv.is_file() else np.zeros((0, 2))
    if np.any(rng[:, 1] <= 0):
        raise EurocError(f"range0 {range_csv}: ranges must be > 0")
    truth_csv = mav / "state_groundtruth_estimate0" / "data.csv"
    truth = None
    if truth_csv.is_file():
        gt = _table(truth_csv, 8, "ground truth")
        try:
            truth = Trajectory(gt[:, 0].copy(), gt[:, 1:4].copy(), gt[:, 4:8].copy())
        except TumError as exc:
            raise EurocError(f"ground truth {truth_csv}: {exc}") from None
    info = _camera_info(cam / "sensor.yaml", camera.width, camera.height)
    return EurocFolder(root, camera, imu[:, :7].copy(), rng[:, :2].copy(), info, truth)


def write_euroc(
    folder: Path,
    measurements: Iterable[Measurement],
    camera_info: CameraModel | Rig | None = None,
    ground_truth: Trajectory | None = None,
) -> Path:
    """Write ``measurements`` as a EuRoC folder (``folder/mav0/...``; frames as PNG, stamps in ns), the
    rangefinder in capataz's ``range0`` extension. How a simulated flight is exported for EuRoC tools.

    ``camera_info``: the camera (mounted looking down) or a whole rig, written to ``cam0/sensor.yaml`` with
    its mount as ``T_BS`` (EuRoC's body is its IMU: a rig whose IMU axes are not the body's is refused)."""
    mav = Path(folder) / "mav0"
    for sub in ("cam0/data", "imu0", "range0", "state_groundtruth_estimate0"):
        (mav / sub).mkdir(parents=True, exist_ok=True)
    cam_rows, imu_rows, range_rows = [], [], []
    for m in measurements:
        ns = round(m.stamp_s * 1e9)
        if isinstance(m, FrameMeasurement):
            cv2.imwrite(str(mav / "cam0" / "data" / f"{ns}.png"), m.image)
            cam_rows.append(f"{ns},{ns}.png")
        elif isinstance(m, ImuMeasurement):
            values = [*m.gyro_rad_s, *m.accel_m_s2]
            imu_rows.append(f"{ns}," + ",".join(repr(float(v)) for v in values))
        elif isinstance(m, RangeMeasurement):
            range_rows.append(f"{ns},{m.range_m!r}")
    (mav / "cam0" / "data.csv").write_text("#timestamp [ns],filename\n" + "".join(r + "\n" for r in cam_rows))
    imu_header = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    imu_header += "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
    (mav / "imu0" / "data.csv").write_text(imu_header + "".join(r + "\n" for r in imu_rows))
    (mav / "range0" / "data.csv").write_text(
        "#timestamp [ns],range [m]\n" + "".join(r + "\n" for r in range_rows)
    )
    if camera_info is not None:
        rig = camera_info if isinstance(camera_info, Rig) else Rig(camera_info)
        if not np.array_equal(rig.R_body_imu, np.eye(3)) or rig.time_offset_s != 0.0:
            raise InputError(
                "EuRoC's body is its IMU: a rig with other IMU axes or a clock offset cannot be written"
            )
        camera_info = rig.camera
        T_body_camera = np.eye(4)
        T_body_camera[:3, :3], T_body_camera[:3, 3] = rig.R_body_camera, rig.t_body_camera_m
        doc = {
            "sensor_type": "camera",
            "camera_model": "pinhole",
            "intrinsics": [
                float(v) for v in (camera_info.fx, camera_info.fy, camera_info.cx, camera_info.cy)
            ],
            "distortion_model": "equidistant"
            if camera_info.distortion.model.value == "fisheye"
            else "radial-tangential",
            "distortion_coefficients": [float(c) for c in camera_info.distortion.coeffs] or [0.0] * 4,
            "resolution": [int(camera_info.width), int(camera_info.height)],
            "T_BS": {"cols": 4, "rows": 4, "data": [float(v) for v in T_body_camera.ravel()]},
        }
        (mav / "cam0" / "sensor.yaml").write_text(yaml.safe_dump(doc))
    if ground_truth is not None:
        rows = [
            f"{round(t * 1e9)}," + ",".join(repr(float(v)) for v in (*p, *q))
            for t, p, q in zip(
                ground_truth.stamps_s, ground_truth.p_world_body_m, ground_truth.q_world_body, strict=True
            )
        ]
        header = "#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n"
        (mav / "state_groundtruth_estimate0" / "data.csv").write_text(
            header + "".join(r + "\n" for r in rows)
        )
    return Path(folder)
