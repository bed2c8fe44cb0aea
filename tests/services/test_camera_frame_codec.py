"""``--frame-codec`` / ``--jpeg-quality``: declared once in the camera's settings, reachable from ``capataz
camera``, ``capataz up`` and its compose form; a frame leaves the camera with the chosen encoding."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from common.wire.frame_codec import DEFAULT_JPEG_QUALITY
from common.wire.messages import Frame
from services.camera.service import camera_settings_from_args, describe_frame, frame_codec_fields
from services.camera.settings import CameraSettings
from services.tools.cli import build_parser, main
from services.tools.up_command import frame_codec_args

ROOT = Path(__file__).resolve().parents[2]
CLUSTER = ROOT / "deploy" / "clusters" / "local2x2.yml"


def _camera(*argv: str) -> CameraSettings:
    return camera_settings_from_args(build_parser().parse_args(["camera", *argv]))


def test_the_default_is_raw_mono8_and_the_options_defaults_are_the_settings() -> None:
    settings = _camera()
    assert settings.frame_codec == CameraSettings().frame_codec == "mono8"
    assert settings.jpeg_quality == CameraSettings().jpeg_quality == DEFAULT_JPEG_QUALITY
    assert frame_codec_fields(settings) == {"encoding": "mono8"}


def test_the_chosen_codec_and_quality_go_into_every_frame() -> None:
    assert frame_codec_fields(_camera("--frame-codec", "png")) == {"encoding": "png"}
    jpeg = _camera("--frame-codec", "jpeg", "--jpeg-quality", "75")
    assert frame_codec_fields(jpeg) == {"encoding": "jpeg", "quality": 75}
    frame = Frame(uav="a", seq=0, stamp_s=0.0, width=4, height=3, pixels=np.zeros((3, 4), np.uint8))
    sent = frame.model_copy(update=frame_codec_fields(jpeg))
    assert sent.encoding == "jpeg" and sent.quality == 75


def test_the_log_line_states_size_codec_and_share_of_raw() -> None:
    frame = Frame(
        uav="a", seq=0, stamp_s=0.0, width=752, height=480, pixels=np.zeros((480, 752), np.uint8),
        encoding="jpeg", quality=90,
    )  # fmt: skip
    assert describe_frame(frame, 119802) == "752x480 jpeg q90: 119.8 kB per frame (33 % of mono8's 361.0 kB)"


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["camera", "--jpeg-quality", "0"], "--jpeg-quality: must be >= 1, got 0"),
        (["up", "--cluster", str(CLUSTER), "--jpeg-quality", "101"], "--jpeg-quality: must be <= 100"),
    ],
)
def test_a_quality_out_of_range_is_one_line_and_exit_2(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(argv)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and expected in lines[0], lines


def test_up_passes_the_codec_on_to_its_camera_and_its_compose_form(tmp_path: Path) -> None:
    def up(*argv: str) -> list[str]:
        return frame_codec_args(build_parser().parse_args(["up", "--cluster", str(CLUSTER), *argv]))

    assert up() == [] and up("--frame-codec", "mono8") == []
    assert up("--frame-codec", "zstd") == ["--frame-codec", "zstd"]
    assert up("--frame-codec", "jpeg", "--jpeg-quality", "80") == [
        "--frame-codec",
        "jpeg",
        "--jpeg-quality",
        "80",
    ]
    path = tmp_path / "compose.yml"
    assert main(["up", "--cluster", str(CLUSTER), "--frame-codec", "png", "--compose", str(path)]) == 0
    command = yaml.safe_load(path.read_text())["services"]["camera"]["command"]
    assert command[-2:] == ["--frame-codec", "png"]
    # the camera's parser takes what up passes on
    assert _camera(*command[command.index("--frame-codec") :]).frame_codec == "png"
