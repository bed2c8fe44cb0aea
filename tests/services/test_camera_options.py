"""One camera option group for every command that needs a camera (services.runtime.camera_options)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import pytest

from common.camera import CameraModel, DistortionModel
from common.datasets.calibration import opencv_yaml_text, ros_yaml_text
from common.localization.office import office_camera
from common.sim.field import wide_angle_camera
from services.estimator.settings import estimator_camera
from services.estimator.settings import settings_from_args as estimator_from_args
from services.localizer.loading import localizer_camera
from services.localizer.settings import settings_from_args as localizer_from_args
from services.runtime.camera_options import (
    CameraOptions,
    add_camera_options,
    camera_from_args,
    camera_options_from_args,
    load_camera,
)
from services.runtime.usage import UsageError
from services.tools.cli import build_parser, main

COMMANDS = ("master", "estimator", "localizer")


def _camera_group(command: str) -> set[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    groups = [g for g in sub._action_groups if (g.title or "").startswith("camera")]
    assert len(groups) == 1, f"{command}: one camera group"
    return {s for a in groups[0]._group_actions for s in a.option_strings}


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_camera_options(parser, CameraModel.default())
    return parser.parse_args(list(argv))


def test_every_command_that_needs_a_camera_has_the_same_group() -> None:
    groups = {command: _camera_group(command) for command in COMMANDS}
    assert groups["master"] == groups["estimator"] == groups["localizer"]
    assert {"--calibration", "--resolution", "--hfov", "--fx", "--distortion"} <= groups["master"]


def test_nothing_given_is_the_command_default_camera() -> None:
    assert camera_from_args(_parse(), CameraModel.default()) == CameraModel.default()
    assert camera_from_args(_parse(), None) is None  # the master's: no lens model
    assert estimator_camera(estimator_from_args(build_parser().parse_args(["estimator"]))) == (
        CameraModel.default()
    )
    assert localizer_camera(localizer_from_args(build_parser().parse_args(["localizer"]))) == office_camera()


def test_resolution_and_fov_make_a_pinhole_and_keep_the_default_fov() -> None:
    camera = camera_from_args(_parse("--resolution", "320x240", "--hfov", "70"), CameraModel.default())
    assert camera == CameraModel.from_hfov(320, 240, 70.0)
    sized = camera_from_args(_parse("--resolution", "376x240"), CameraModel.default())
    assert sized is not None and sized.width == 376 and np.degrees(sized.hfov_rad) == pytest.approx(90.0)


@pytest.mark.parametrize("writer", [opencv_yaml_text, ros_yaml_text])
def test_a_calibration_file_reaches_the_estimator_and_the_localizer(tmp_path: Path, writer: object) -> None:
    path = tmp_path / "camera.yaml"
    path.write_text(writer(wide_angle_camera()))  # type: ignore[operator]
    estimator = estimator_from_args(build_parser().parse_args(["estimator", "--calibration", str(path)]))
    localizer = localizer_from_args(build_parser().parse_args(["localizer", "--calibration", str(path)]))
    for camera in (estimator_camera(estimator), localizer_camera(localizer)):
        assert camera.distortion.model is DistortionModel.RADTAN
        assert np.allclose(camera.K, wide_angle_camera().K)


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (("--hfov", "180"), "--hfov"),
        (("--resolution", "0x240"), "--resolution"),
        (("--resolution", "abc"), "--resolution"),
        (("--fx", "100", "--hfov", "60"), "not both"),
        (("--calibration", "c.yaml", "--fx", "100"), "not two"),
        (("--distortion", "fisheye"), "needs intrinsics"),
        (("--fx", "100", "--distortion", "fisheye", "--distortion-coeffs", "0.1"), "takes 4"),
        (("--fx", "100", "--distortion-coeffs", "a"), "--distortion-coeffs"),
    ],
)
def test_bad_camera_options_are_one_usage_line(argv: tuple[str, ...], option: str) -> None:
    with pytest.raises(UsageError) as info:
        camera_options_from_args(_parse(*argv))
    assert option in str(info.value) and "\n" not in str(info.value)


def test_a_bad_camera_option_exits_2_with_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    for command in COMMANDS:
        assert main([command, "--hfov", "0"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "--hfov" in err, err


def test_a_fisheye_file_with_zero_coefficients_is_said_in_one_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "fisheye.yaml"
    path.write_text(
        "image_width: 320\nimage_height: 240\ndistortion_model: equidistant\n"
        "camera_matrix: {rows: 3, cols: 3, data: [200, 0, 159.5, 0, 200, 119.5, 0, 0, 1]}\n"
        "distortion_coefficients: {rows: 1, cols: 4, data: [0, 0, 0, 0]}\n"
    )
    with caplog.at_level(logging.WARNING):
        camera = load_camera(CameraOptions(calibration=path), None)
    assert camera is not None and camera.distortion.model is DistortionModel.FISHEYE
    lines = [r.getMessage() for r in caplog.records if "all-zero" in r.getMessage()]
    assert len(lines) == 1 and "not a pinhole" in lines[0] and "\n" not in lines[0]
