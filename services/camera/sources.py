"""The camera's sources: what it publishes, as one time-ordered stream of samples. A simulated flight
(services/camera/flights.py) or a recorded input: an image folder, a ROS bag, a EuRoC folder or a capataz
MCAP recording, each opened (and checked) before the first frame.

Opening refuses a bad input with one :class:`~common.errors.InputError` line (the CLI's exit code 1):
nothing is published from a recording that would stop half-way (a yaw reset the user would not see).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from common.camera import CameraModel
from common.datasets.calibration import CalibrationError
from common.datasets.euroc import open_euroc
from common.datasets.images import open_image_folder
from common.datasets.rig_files import load_rig
from common.datasets.rosbag import open_bag
from common.datasets.tum import Trajectory
from common.errors import InputError
from common.estimation.measurements import Measurement
from common.rig import Rig
from common.types import FloatArray
from common.wire.schema import WireModel
from services.camera.settings import CameraSettings

#: what a skipped sample is reported to: (kind, why)
OnSkip = Callable[[str, str], None]


@dataclass(frozen=True)
class OdometrySample:
    """A simulated odometry pose (the office flight's stand-in for VO: truth plus noise), for ``pose/vo``."""

    stamp_s: float
    p_world_body_m: FloatArray
    #: roll, pitch, yaw (rad)
    euler_rad: FloatArray


#: what a source's stream carries: sensor samples and frames, and (office flight) odometry poses
Sample = Measurement | OdometrySample

#: a source's truth: ``(uav, seq, stamp_s, i)`` -> the true pose message of the i-th frame of a round
TruthOf = Callable[[str, int, float, int], WireModel]


@dataclass(frozen=True)
class CameraSource:
    """An opened source: a description, the calibration it carries, and its stream of samples (a new
    iterator each round of ``--loop``)."""

    description: str
    measurements: Callable[[OnSkip | None], Iterator[Sample]]
    camera_info: CameraModel | None = None
    ground_truth: Trajectory | None = None
    frames: int | None = None
    #: frame size (every frame of the source has it)
    width: int = 0
    height: int = 0
    #: the simulation's true pose of each frame (published on ``truth`` after it), None for a recording
    truth: TruthOf | None = None
    #: True: frames go out at ``--fps`` frames per second (a simulation); False: at the recorded rate
    #: times ``--rate`` (a recording)
    paced_by_fps: bool = False
    #: the rig the source carries (a simulation's, a rig file's, EuRoC's sensor.yaml with T_BS); None: only
    #: ``camera_info`` (mounted looking down) or nothing
    rig: Rig | None = None

    def stream_rig(self) -> Rig | None:
        """The rig the camera publishes with the stream: the source's, else its calibration looking down."""
        if self.rig is not None:
            return self.rig
        return None if self.camera_info is None else Rig(self.camera_info)


def preloaded(source: CameraSource) -> CameraSource:
    """The same source with every measurement read into memory first (reading costs no frame time)."""
    items = list(source.measurements(None))
    return replace(source, measurements=lambda _skip: iter(items))


def with_calibration(source: CameraSource, path: Path) -> CameraSource:
    """``source`` with the rig of a calibration file (any format :func:`~common.datasets.rig_files.load_rig`
    reads: OpenCV or ROS camera_info YAML, a capataz rig, EuRoC's sensor.yaml, Kalibr's camchain; it replaces
    a recording's own CameraInfo); the calibration must be of the recording's frame size."""
    rig = load_rig(path)
    camera = rig.camera
    if source.width and (camera.width, camera.height) != (source.width, source.height):
        raise CalibrationError(
            f"calibration file {path}: {camera.width}x{camera.height}, but the frames are "
            f"{source.width}x{source.height}"
        )
    return replace(source, camera_info=camera, rig=rig)


def open_source(
    images: Path | None = None,
    stamps: Path | None = None,
    start: int = 0,
    stop: int | None = None,
    step: int = 1,
    fps: float = 0.0,
    bag: Path | None = None,
    topics: dict[str, str | None] | None = None,
    euroc: Path | None = None,
    mcap: Path | None = None,
    uav: str = "uav0",
) -> CameraSource | None:
    """Open the one recorded input given (None: none given, the camera simulates)."""
    given = [
        name
        for name, value in (("--images", images), ("--bag", bag), ("--euroc", euroc), ("--mcap", mcap))
        if value is not None
    ]
    if len(given) > 1:
        raise InputError(f"give one input, not {' and '.join(given)}")
    if stamps is not None and images is None:
        raise InputError("--stamps needs --images")
    if images is not None:
        folder = open_image_folder(images, stamps, start, stop, step, fps)
        return CameraSource(
            f"{len(folder)} images of {folder.path} ({folder.width}x{folder.height})",
            lambda _skip: iter(folder.frames()),
            frames=len(folder),
            width=folder.width,
            height=folder.height,
        )
    if bag is not None:
        opened = open_bag(bag, **(topics or {}))
        return CameraSource(
            f"bag {opened.path} (image {opened.topics.image}, imu {opened.topics.imu}, "
            f"range {opened.topics.range})",
            opened.measurements,
            camera_info=opened.camera_info,
            frames=opened.counts.get(opened.topics.image),
            width=opened.width,
            height=opened.height,
        )
    if euroc is not None:
        folder_e = open_euroc(euroc)
        return CameraSource(
            f"EuRoC {folder_e.root} ({len(folder_e.camera)} frames, {len(folder_e.imu)} IMU samples)",
            lambda _skip: folder_e.measurements(),
            camera_info=folder_e.camera_info,
            rig=_euroc_rig(folder_e.root),
            ground_truth=folder_e.ground_truth,
            frames=len(folder_e.camera),
            width=folder_e.camera.width,
            height=folder_e.camera.height,
        )
    if mcap is not None:
        from common.recordings.mcap import open_recording

        recording = open_recording(mcap, uav)
        return CameraSource(
            f"capataz recording {recording.path} ({recording.frames} frames of {recording.uav})",
            lambda _skip: recording.measurements(),
            frames=recording.frames,
            width=recording.width,
            height=recording.height,
        )
    return None


def _euroc_rig(root: Path) -> Rig | None:
    """The rig of a EuRoC folder's ``mav0/cam0/sensor.yaml`` (its ``T_BS`` mounts the camera on the body, the
    IMU's frame); None when the file is missing."""
    path = Path(root) / "mav0" / "cam0" / "sensor.yaml"
    return load_rig(path) if path.is_file() else None


def open_camera_source(settings: CameraSettings) -> CameraSource | None:
    """:func:`open_source` of a camera's settings."""
    topics = {
        name: getattr(settings, name)
        for name in ("image_topic", "imu_topic", "range_topic", "camera_info_topic")
    }
    if settings.calibration is not None and not any(
        getattr(settings, name) is not None for name in ("images", "bag", "euroc", "mcap")
    ):
        raise InputError("--calibration needs a recorded input (--images, --bag, --euroc or --mcap)")
    source = open_source(
        settings.images,
        settings.stamps,
        settings.start,
        settings.stop,
        settings.step,
        settings.fps,
        settings.bag,
        topics,
        settings.euroc,
        settings.mcap,
        settings.uavs[0],
    )
    if source is not None and settings.calibration is not None:
        source = with_calibration(source, settings.calibration)
    return source


def add_source_arguments(parser: argparse.ArgumentParser) -> None:
    """Recorded-input options: ``--images`` (stamps, slice), ``--bag``, ``--euroc``, ``--mcap``."""
    group = parser.add_argument_group("recorded input (instead of a simulation; one of them)")
    group.add_argument("--images", type=Path, help="a folder of images (natural order: 2.png before 10.png)")
    group.add_argument(
        "--stamps", type=Path, help="per-image stamps: 'index,stamp' CSV (s) or EuRoC data.csv (ns)"
    )
    group.add_argument("--start", type=int, default=0, help="first image (position in natural order)")
    group.add_argument("--stop", type=int, help="stop before this image")
    group.add_argument("--step", type=int, default=1, help="take every STEP-th image")
    group.add_argument(
        "--calibration", type=Path, help="camera calibration (OpenCV YAML or ROS camera_info YAML)"
    )
    group.add_argument("--bag", type=Path, help="a ROS 1 .bag or a ROS 2 bag (folder, .mcap or .db3)")
    group.add_argument("--image-topic", help="bag topic of sensor_msgs/Image or CompressedImage")
    group.add_argument("--imu-topic", help="bag topic of sensor_msgs/Imu")
    group.add_argument("--range-topic", help="bag topic of sensor_msgs/Range")
    group.add_argument("--camera-info-topic", help="bag topic of sensor_msgs/CameraInfo")
    group.add_argument("--euroc", type=Path, help="a EuRoC folder (mav0/cam0, imu0, ground truth)")
    group.add_argument("--mcap", type=Path, help="a capataz recording (capataz record) to replay")
    group.add_argument(
        "--rate",
        type=float,
        default=1.0,
        help="replay speed of a recording (1 = recorded rate, 0 = as fast as consumed)",
    )
