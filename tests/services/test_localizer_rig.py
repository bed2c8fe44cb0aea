"""The localizer follows the stream's rig (issue 26): a rig whose camera is not the localizer's is adopted
(its frames taken, the filter rebuilt for that camera before the next step), one of the same camera changes
nothing, a frame of a rig not received is refused and counted; with camera options the stream's rig is not
followed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from common.camera import CameraModel
from common.rig import Rig
from common.wire.messages import Frame
from services.localizer.service import LocalizerService
from services.localizer.settings import LocalizerSettings
from services.runtime.camera_options import CameraOptions
from services.runtime.transport import TransportSettings
from tests.services.test_estimator_gate import CAMERA, _sample


def _frames(
    service: LocalizerService, rig_id: str | None, n: int = 3, camera: CameraModel | None = None
) -> None:
    camera = service.camera if camera is None else camera
    pixels = np.zeros((camera.height, camera.width), np.uint8)
    for k in range(n):
        frame = Frame(uav="uav0", seq=k, stamp_s=0.1 * k, width=camera.width, height=camera.height,
                      pixels=pixels, rig_id=rig_id)  # fmt: skip
        service._on_frame(_sample(frame, "capataz/uav/uav0/camera", CAMERA))  # type: ignore[arg-type]


def test_a_rig_of_another_camera_is_adopted_and_the_same_camera_changes_nothing() -> None:
    service = LocalizerService("l", 0, TransportSettings(), LocalizerSettings())
    assert service.rigs is not None
    same = Rig(service.camera)
    other = Rig(
        replace(service.camera, fx=service.camera.fx * 1.1, width=400, height=300, cx=199.5, cy=149.5)
    )
    for rig in (same, other):
        service.rigs.add(rig)
    built_with = service.path.camera
    _frames(service, other.rig_id, camera=other.camera)
    assert service.counters.get("rigs_adopted") == 1 and service.counters.get("frames_in") == 3
    assert service.camera == other.camera and service.path.camera == built_with  # rebuilt on its thread
    service._take_pending_camera()
    assert service.path.camera == other.camera
    service = LocalizerService("l", 0, TransportSettings(), LocalizerSettings())
    _frames(service, "0123456789abcdef")
    assert service.counters.get("refused_camera_unknown_rig") == 3
    service = LocalizerService("l", 0, TransportSettings(), LocalizerSettings())
    assert service.rigs is not None
    service.rigs.add(same)
    _frames(service, same.rig_id)
    assert service.counters.get("frames_in") == 3


def test_camera_options_mean_the_stream_rig_is_not_followed() -> None:
    settings = LocalizerSettings(camera=CameraOptions(width=320, height=240, hfov_deg=70.0))
    service = LocalizerService("l", 0, TransportSettings(), settings)
    assert service.rigs is None
    _frames(service, "0123456789abcdef")
    assert service.counters.get("frames_in") == 3
