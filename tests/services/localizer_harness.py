"""What the localizer service tests share: the object flight's model and calibration files, the in-process
reference the service must match, and a running service linked to a test session (frames in, poses out)."""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import zenoh

from common.datasets.calibration import opencv_yaml_text
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerState
from common.localization.tracking import track_model
from common.sim.objects import object_camera, tabletop_model
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Frame, PoseEstimate
from services.localizer import LocalizerService, LocalizerSettings
from services.localizer.loading import load_scene, localizer_camera
from services.runtime.camera_options import CameraOptions
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, matched, peer


def frame(seq: int, stamp_s: float, pixels: np.ndarray, uav: str = "uav0") -> Frame:
    """A camera frame of ``pixels`` (its size read from the array)."""
    return Frame(
        uav=uav, seq=seq, stamp_s=stamp_s, width=pixels.shape[1], height=pixels.shape[0], pixels=pixels
    )


def obj_text(vertices_world_m: np.ndarray, faces: Sequence[Sequence[int]]) -> str:
    """A mesh as a Wavefront OBJ file (what a user exports from CAD)."""
    lines = [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in vertices_world_m]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in faces]
    return "\n".join(lines) + "\n"


def object_settings(folder: Path, initial_pose: tuple[float, ...], seed: int) -> LocalizerSettings:
    """Settings of the object flight as a user gives them: the tabletop model file, the object camera's
    calibration file and a camera-from-world initial pose (OpenCV rvec + tvec), both files written to
    ``folder``."""
    model = tabletop_model()
    (folder / "tabletop.obj").write_text(obj_text(model.vertices_world_m, model.faces))
    (folder / "camera.yaml").write_text(opencv_yaml_text(object_camera()))
    return LocalizerSettings(
        model=folder / "tabletop.obj",
        camera=CameraOptions(calibration=folder / "camera.yaml"),
        camera_mount="camera",
        initial_pose=initial_pose,
        seed=seed,
    )


def in_process(
    settings: LocalizerSettings, images: Sequence[np.ndarray], times_s: np.ndarray
) -> list[TrackerState]:
    """What the service must publish: the tracker run in this process with the service's settings."""
    tracker = ModelTracker(load_scene(settings), localizer_camera(settings), settings.tracker_settings())
    rng = np.random.default_rng(settings.seed)
    return list(track_model(tracker, images, times_s, tracker.start(settings.start_pose()), rng))


@contextmanager
def linked(
    service: LocalizerService, endpoint: str
) -> Iterator[tuple[zenoh.Publisher, queue.Queue[PoseEstimate]]]:
    """``service`` running in a thread, and a session routed to it both ways: yields the publisher of
    uav0's camera key and the queue of the poses it publishes; stops the service (and checks it stopped)
    on the way out."""
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    poses: queue.Queue[PoseEstimate] = queue.Queue()
    try:
        assert service.started.wait(WAIT_S), "service did not start"
        with open_session(peer(endpoint)) as session:
            subscriber = session.declare_subscriber(
                keys.pose_pf_key("uav0"),
                lambda s: poses.put(decode(zbytes(s.payload), zbytes(s.attachment), PoseEstimate)),
            )
            publisher = session.declare_publisher(keys.camera_key("uav0"))
            assert matched(publisher) and matched(service._publisher)  # both directions are routed
            try:
                yield publisher, poses
            finally:
                subscriber.undeclare()
                publisher.undeclare()
    finally:
        service.request_stop()
        runner.join(5.0)
    assert not runner.is_alive()
