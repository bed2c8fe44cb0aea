"""A recording replayed with ``capataz camera`` alone gives the consumers its rig (issue 26), per format: a
ROS 2 bag (its ``CameraInfo``, mounted looking down) and a EuRoC folder (``sensor.yaml`` with ``T_BS``: a
tilted camera with a lever arm). The camera publishes the rig, every frame names it, the master measures
every frame with it, and the estimator and a localizer given no camera adopt it. (The image folder with a
calibration file, a changed rig and a frame naming an unknown rig: ``test_rig_stream.py``.)"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
import zenoh

from common.camera import CameraModel, Distortion, DistortionModel
from common.datasets.euroc import write_euroc
from common.datasets.rosbag_writer import write_bag
from common.geometry import R_BODY_CAMERA_DOWN
from common.members import Role
from common.provenance import Provenance
from common.rig import Rig
from common.sim.flight import hover_flight
from common.sim.stream import flight_measurements
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import YawEstimate
from common.wire.rig import RigMessage, rig_from_message
from services.camera import CameraService, CameraSettings
from services.estimator import EstimatorService, EstimatorSettings
from services.localizer.service import LocalizerService
from services.localizer.settings import LocalizerSettings
from services.master import MasterService, MasterSettings
from services.runtime.service import ServiceRuntime
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, hub, peer, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 8


def _tilt_x(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]) @ R_BODY_CAMERA_DOWN


def _recording(kind: str, tmp_path: Path) -> tuple[CameraSettings, Rig]:
    flight = hover_flight(seed=1, n_frames=N_FRAMES)
    lens = flight.camera
    camera = CameraModel(
        width=lens.width, height=lens.height, fx=lens.fx, fy=lens.fy, cx=lens.cx, cy=lens.cy,
        distortion=Distortion(DistortionModel.RADTAN, (-0.02, 0.005, 0.0, 0.0, 0.0)),
    )  # fmt: skip
    stream = list(flight_measurements(flight))
    if kind == "bag":
        path = write_bag(tmp_path / "flight_ros2", stream, camera, "ros2-mcap")
        return CameraSettings(bag=path, fps=0.0, in_flight=1), Rig(camera)
    rig = Rig(camera, R_body_camera=_tilt_x(8.0), t_body_camera_m=np.array([0.04, -0.01, 0.02]))
    path = write_euroc(tmp_path / "flight_euroc", stream, rig)
    return CameraSettings(euroc=path, fps=0.0, in_flight=1), rig


def _run(service: ServiceRuntime) -> threading.Thread:
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize("kind", ["bag", "euroc"])
def test_a_recording_alone_gives_the_master_the_estimator_and_the_localizer_its_rig(
    kind: str, tmp_path: Path
) -> None:
    camera_settings, expected = _recording(kind, tmp_path)
    yaws: list[YawEstimate] = []
    published: list[Rig] = []

    def on_yaw(sample: zenoh.Sample) -> None:
        yaws.append(decode(zbytes(sample.payload), zbytes(sample.attachment), YawEstimate))

    def on_rig(sample: zenoh.Sample) -> None:
        published.append(
            rig_from_message(decode(zbytes(sample.payload), zbytes(sample.attachment), RigMessage))
        )

    with hub() as endpoint:
        master = MasterService("m", 0, peer(endpoint), MasterSettings(election=False))
        estimator = EstimatorService("e", 0, peer(endpoint), EstimatorSettings())
        localizer = LocalizerService("l", 0, peer(endpoint), LocalizerSettings())  # all defaults: no camera
        assert localizer.camera != expected.camera
        camera = CameraService("c", 0, peer(endpoint), camera_settings)
        threads = [_run(master), _run(estimator), _run(localizer)]
        with open_session(peer(endpoint)) as session:
            subscribers = [
                session.declare_subscriber(keys.yaw_key("uav0"), on_yaw),
                session.declare_subscriber(keys.rig_key("uav0"), on_rig),
            ]
            assert all(s.started.wait(WAIT_S) for s in (master, estimator, localizer))
            threads.append(_run(camera))
            wanted = set(range(1, N_FRAMES))
            assert wait_until(lambda: wanted <= {e.seq for e in yaws}, 60.0), len(yaws)
            assert wait_until(lambda: estimator.counters.get("rigs_adopted") == 1, 30.0), estimator.counters
            assert wait_until(lambda: localizer.counters.get("rigs_adopted") == 1, 30.0), localizer.counters
            for subscriber in subscribers:
                subscriber.undeclare()
        for service in (camera, master, estimator, localizer):
            service.request_stop()
        for thread in threads:
            thread.join(10.0)
    assert published and all(rig == expected for rig in published), published
    assert master.counters.get("rigs_received") == 1 and not master.counters.get("refused_camera_unknown_rig")
    assert not estimator.counters.get("refused_camera_unknown_rig")
    assert np.allclose(estimator.estimator.R_body_camera, expected.R_body_camera, atol=1e-12)
    # (a frame that reaches the localizer before the rig is refused and counted: test_rig_stream.py)
    assert localizer.camera == expected.camera and localizer.counters.get("rigs_adopted") == 1
    by_seq = {e.seq: e for e in yaws}
    assert all(by_seq[k].provenance is not Provenance.INITIAL for k in wanted)


def test_an_image_folder_with_its_calibration_gives_the_localizer_its_camera(
    shared_data: Path, tmp_path: Path
) -> None:
    """The real cube video and its calibration through the camera alone: a localizer given only the model and
    the start pose (no camera options) adopts the stream's camera and tracks the cube."""
    from common.datasets.calibration import ros_yaml_text
    from services.tools.bench.localizer_cube import load_cube

    cube_dir = shared_data / "visp_cube"
    cube = load_cube(cube_dir)
    calibration = tmp_path / "cube_camera.yaml"
    calibration.write_text(ros_yaml_text(cube.camera))
    rvec, tvec = cube.start.rvec_tvec()
    settings = LocalizerSettings(
        model=cube_dir / "cube.cao", camera_mount="camera", initial_pose=(*rvec, *tvec)
    )
    frames = 12
    with hub() as endpoint:
        localizer = LocalizerService("l", 0, peer(endpoint), settings)
        assert localizer.camera != cube.camera  # built with the default camera
        camera = CameraService(
            "c", 0, peer(endpoint),
            CameraSettings(images=cube_dir / "cube", stop=frames, calibration=calibration, fps=10.0,
                           sensors=False, wait_for=Role.LOCALIZER),
        )  # fmt: skip
        threads = [_run(localizer)]
        assert localizer.started.wait(WAIT_S)
        threads.append(_run(camera))

        # every frame is published or, at the stream's start on a busy host, refused before its rig arrived
        def accounted() -> int:
            return localizer.counters.get("poses_out") + localizer.counters.get("refused_camera_unknown_rig")

        assert wait_until(lambda: accounted() >= frames, 60.0), accounted()
        for service in (camera, localizer):
            service.request_stop()
        for thread in threads:
            thread.join(10.0)
    assert localizer.counters.get("rigs_adopted") == 1 and localizer.path.camera == cube.camera
    poses = localizer.counters.get("poses_out")
    assert poses >= frames // 2 and localizer.counters.get("frames_tracking") >= poses - 2, poses
