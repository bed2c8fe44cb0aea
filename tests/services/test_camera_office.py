"""The camera's office flight feeds the localizer exactly the frames of its in-process reference."""

from __future__ import annotations

import numpy as np

from common.sim.office_run import simulate_run
from services.camera.flights import office_frames
from services.camera.service import camera_settings_from_args
from services.camera.settings import CameraSettings
from services.tools.cli import build_parser


def test_office_frames_equal_the_localizers_simulated_run() -> None:
    settings = CameraSettings(flight="office", frames=4, seed=3)
    published = list(office_frames(settings))
    reference = simulate_run(n_frames=4, seed=3)
    assert [seq for seq, _, _ in published] == [0, 1, 2, 3]
    assert np.allclose([stamp for _, stamp, _ in published], reference.flight.times_s)
    for (_, _, image), expected in zip(published, reference.images, strict=True):
        assert image.shape == (240, 320)
        assert np.array_equal(image, expected)


def test_office_flight_from_the_command_line_has_no_ground_flight() -> None:
    args = build_parser().parse_args(["camera", "--flight", "office", "--uav", "uav1", "--frames", "10"])
    settings = camera_settings_from_args(args)
    assert settings.flight == "office" and settings.uavs == ("uav1",)
    assert (settings.width, settings.height) == (None, None)


def test_explicit_resolution_is_kept() -> None:
    args = build_parser().parse_args(["camera", "--resolution", "640x360"])
    assert (camera_settings_from_args(args).width, camera_settings_from_args(args).height) == (640, 360)
