"""The camera and up commands on recordings as users have them: one clear refusal (one line, its exit code,
no traceback) for an empty image folder, mixed sizes, a file path, a calibration of another size or a
truncated bag (the readers themselves are tested in tests/common/datasets)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.camera import CameraModel
from common.datasets.calibration import CalibrationError, ros_yaml_text
from common.datasets.rosbag_writer import write_bag
from common.sim.flight import hover_flight
from common.sim.stream import flight_measurements
from services.camera.settings import CameraSettings
from services.camera.sources import open_camera_source
from tests.common.datasets.test_images import _folder


@pytest.mark.zenoh  # starts the camera command (it refuses the input before opening a session)
@pytest.mark.parametrize("kind", ["empty", "mixed", "file"])
def test_camera_command_refuses_bad_folders_in_one_line_with_exit_code_1(tmp_path: Path, kind: str) -> None:
    folder = _folder(tmp_path, ["0.png", "1.png"])
    if kind == "empty":
        folder = tmp_path / "nothing"
        folder.mkdir()
    elif kind == "mixed":
        cv2.imwrite(str(folder / "2.png"), np.zeros((10, 10), np.uint8))
    else:
        folder = folder / "0.png"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.tools.cli",
            "camera",
            "--images",
            str(folder),
            "--wait-master",
            "0",
            "--listen",
            "tcp/127.0.0.1:0",
            "--no-multicast",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    lines = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    # not a folder of images at all: a usage error (exit 2, services/camera/images.py); a folder that cannot
    # be replayed (mixed sizes): a runtime error naming the problem (exit 1)
    expected = (1, "mixed image sizes") if kind == "mixed" else (2, "--images")
    assert result.returncode == expected[0]
    assert len(lines) == 1 and expected[1] in lines[0], lines
    assert "Traceback" not in result.stderr


def test_calibration_file_must_match_the_folders_image_size(tmp_path: Path) -> None:
    folder = _folder(tmp_path, ["0.png", "1.png"])  # 64x48
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text(ros_yaml_text(CameraModel.from_hfov(64, 48, 90.0)))
    bad.write_text(ros_yaml_text(CameraModel.default()))  # 752x480
    source = open_camera_source(CameraSettings(images=folder, calibration=good))
    assert source is not None and source.camera_info == CameraModel.from_hfov(64, 48, 90.0)
    with pytest.raises(CalibrationError, match="752x480, but the frames are 64x48"):
        open_camera_source(CameraSettings(images=folder, calibration=bad))


@pytest.mark.zenoh  # starts the up command (it refuses the folder before starting any process)
def test_up_refuses_a_bad_image_folder_before_starting_anything(tmp_path: Path) -> None:
    folder = _folder(tmp_path, ["0.png"])
    cv2.imwrite(str(folder / "1.png"), np.zeros((10, 10), np.uint8))
    cluster = Path(__file__).resolve().parents[2] / "deploy" / "clusters" / "local2x2.yml"
    result = subprocess.run(
        [sys.executable, "-m", "services.tools.cli", "up", "--cluster", str(cluster), "--port", "0",
         "--images", str(folder), "--logs", str(tmp_path / "logs")],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    lines = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    assert result.returncode == 1 and len(lines) == 1 and "mixed image sizes" in lines[0], lines
    assert not (tmp_path / "logs").exists()  # no process was started


@pytest.mark.zenoh  # starts the camera command (it refuses the input before opening a session)
def test_camera_command_refuses_a_truncated_bag_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "t.bag"
    write_bag(path, list(flight_measurements(hover_flight(seed=0, n_frames=6))), None, "ros1")
    path.write_bytes(path.read_bytes()[:300])
    result = subprocess.run(
        [sys.executable, "-m", "services.tools.cli", "camera", "--bag", str(path), "--wait-master", "0",
         "--listen", "tcp/127.0.0.1:0", "--no-multicast"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    lines = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    assert result.returncode == 1 and len(lines) == 1, lines
    assert "not a readable ROS 1 or ROS 2 bag" in lines[0] and str(path) in lines[0], lines
