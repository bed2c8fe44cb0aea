"""Settings filled by field name (services.runtime.fields), and the services' parsers that rely on it: an
option whose ``dest`` is not its field's name would silently keep the field's default."""

from __future__ import annotations

import argparse

import pytest

from common.dispatch import Balance, DispatchSettings, SpeedSource
from common.errors import CapatazError
from common.streams import FrameGateSettings
from services.camera.service import camera_settings_from_args
from services.camera.settings import CameraSettings
from services.foreman.service import ForemanSettings
from services.localizer.settings import LocalizerSettings, register_arguments, settings_from_args
from services.master.settings import MasterSettings, master_settings_from_args
from services.runtime.cli import add_transport_arguments, dispatch_from_args, parse_size
from services.runtime.fields import field_names, settings_from
from services.tools.cli import build_parser
from services.worker.service import WorkerSettings

#: the camera option group's dests (services.runtime.camera_options: one group for every command)
CAMERA_GROUP = {
    "calibration",
    "resolution",
    "hfov_deg",
    "fx",
    "fy",
    "cx",
    "cy",
    "distortion",
    "distortion_coeffs",
}


def test_later_sources_and_derived_values_win_and_unknown_names_are_ignored() -> None:
    first = argparse.Namespace(max_rate=2.0, silence_s=3.0, not_a_field=1)
    second = argparse.Namespace(silence_s=4.0)
    gate = settings_from(FrameGateSettings, first, second, max_future_s=0.5)
    assert (gate.max_rate, gate.silence_s, gate.max_future_s) == (2.0, 4.0, 0.5)
    assert gate.confirm_frames == FrameGateSettings().confirm_frames  # found nowhere: the default


def test_a_settings_object_is_a_source_too() -> None:
    master = MasterSettings(max_seq_jump=20, confirm_frames=7)
    gate = master.gate_settings()
    assert (gate.max_seq_jump, gate.confirm_frames) == (20, 7)
    assert gate.silence_s == FrameGateSettings().silence_s
    dispatch = settings_from(DispatchSettings, argparse.Namespace(balance=Balance.NONE, suspend_s=2.0))
    assert (dispatch.balance, dispatch.suspend_s) == (Balance.NONE, 2.0)


def test_field_names_refuses_a_type_that_is_no_settings() -> None:
    # the shared clock bounds (StreamClockSettings) first, then the gate's own
    assert field_names(FrameGateSettings) == (
        "max_rate",
        "max_future_s",
        "max_seq_jump",
        "max_stamp_jump_s",
        "confirm_frames",
        "silence_s",
    )
    with pytest.raises(TypeError, match="neither"):
        field_names(int)


@pytest.mark.parametrize("text", ["752", "752x", "axb", "1x2x3", ""])
def test_parse_size_refuses_what_is_not_two_integers(text: str) -> None:
    with pytest.raises(CapatazError, match=f"--resolution must look like 752x480, got {text!r}"):
        parse_size(text, "--resolution", "752x480")
    assert parse_size("640X360", "--resolution", "752x480") == (640, 360)


def _options_without_a_field(command: str, fields: set[str]) -> set[str]:
    shared = argparse.ArgumentParser()
    add_transport_arguments(shared)  # every service's (TransportSettings)
    ignored = set(vars(shared.parse_args([]))) | {"command", "handler", "verbose", "quiet", "_parser"}
    return set(vars(build_parser().parse_args([command]))) - fields - ignored


def test_an_option_without_a_field_of_its_name_is_one_the_builder_derives() -> None:
    # an option added with another dest would silently keep the field's default: the exceptions are listed
    assert _options_without_a_field("localizer", set(LocalizerSettings.model_fields)) == {
        "trajectory",
        *CAMERA_GROUP,  # camera_options_from_args
    }
    camera = _options_without_a_field("camera", set(CameraSettings.model_fields))
    assert camera == {"resolution", "uav", "no_sensors", "write_calibration"}
    assert _options_without_a_field("foreman", set(ForemanSettings.model_fields)) == {
        "balance", "compute", "min_deadline_ms", "speed",  # dispatch_from_args
    }  # fmt: skip
    transport = set(vars(build_parser().parse_args(["camera"]))) & set(
        vars(build_parser().parse_args(["worker"]))
    )
    worker = set(vars(build_parser().parse_args(["worker"]))) - transport - set(WorkerSettings.model_fields)
    assert worker == set()


def test_worker_and_foreman_options_reach_their_fields() -> None:
    worker = settings_from(
        WorkerSettings,
        build_parser().parse_args(["worker", "--queue", "3", "--stream-ttl", "5", "--max-streams", "7"]),
    )
    assert (worker.queue, worker.stream_ttl_s, worker.max_streams) == (3, 5.0, 7)
    args = build_parser().parse_args(["foreman", "--stream-ttl", "9", "--balance", "none"])
    foreman = settings_from(ForemanSettings, args, dispatch=dispatch_from_args(args))
    assert (foreman.stream_ttl_s, foreman.dispatch.balance) == (9.0, Balance.NONE)


def test_every_localizer_option_reaches_its_field() -> None:
    parser = argparse.ArgumentParser()
    register_arguments(parser)
    args = parser.parse_args(
        ["--hfov", "70", "--mount", "down", "--position-spread", "0.3", "--angle-spread", "5",
         "--velocity-noise", "0.4", "--angular-noise", "10", "--vo-jump", "3", "--resolution", "640x360",
         "--scoring", "per_edge", "--filter", "tracker", "--initial-state", "1", "2", "3", "0", "0", "0.5"]
    )  # fmt: skip
    settings = settings_from_args(args)
    assert (settings.camera.hfov_deg, settings.camera_mount) == (70.0, "down")
    assert (settings.position_spread_m, settings.angle_spread_deg) == (0.3, 5.0)
    assert (settings.velocity_noise_m_s, settings.angular_noise_deg_s, settings.vo_jump_m_s) == (
        0.4,
        10.0,
        3.0,
    )
    assert (settings.camera.width, settings.camera.height) == (640, 360)
    assert settings.scoring.value == "per_edge" and settings.filter.value == "tracker"
    assert settings.initial_state == (1.0, 2.0, 3.0, 0.0, 0.0, 0.5)


def test_every_master_option_reaches_its_stage() -> None:
    args = build_parser().parse_args(
        ["master", "--grid", "6x4", "--patch-size", "16", "--pyramid-level", "0", "--balance", "none",
         "--speed", "reported", "--min-deadline-ms", "500", "--compute", "--budget-ms", "800"]
    )  # fmt: skip
    settings = master_settings_from_args(args)
    yaw = settings.yaw
    assert (yaw.grid_cols, yaw.grid_rows, yaw.patch_size_px, yaw.pyramid_level) == (6, 4, 16, 0)
    dispatch = settings.dispatch
    assert (dispatch.balance, dispatch.speed_source) == (Balance.NONE, SpeedSource.REPORTED)
    assert (dispatch.min_deadline_s, dispatch.self_compute, settings.budget_s) == (0.5, True, 0.8)
    assert settings.gate_settings().max_seq_jump == settings.max_seq_jump


def test_every_camera_option_reaches_its_field() -> None:
    args = build_parser().parse_args(
        ["camera", "--wait-master", "2.5", "--no-sensors", "--in-flight", "2", "--start", "3", "--step", "2",
         "--rate", "0.5", "--image-topic", "/cam", "--uav", "a", "--uav", "b", "--frames", "9"]
    )  # fmt: skip
    settings = camera_settings_from_args(args)
    assert (settings.wait_master_s, settings.sensors, settings.in_flight) == (2.5, False, 2)
    assert (settings.start, settings.step, settings.rate, settings.image_topic) == (3, 2, 0.5, "/cam")
    assert (settings.uavs, settings.frames) == (("a", "b"), 9)
