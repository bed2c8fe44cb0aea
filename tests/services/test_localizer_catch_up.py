"""The localizer over Zenoh keeps the frames that arrive while the first frame is searched and catches up
through them in order: every frame gets its pose, the same as the in-process tracker's, none dropped."""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from common.datasets.calibration import opencv_yaml_text
from common.localization.tracker import ModelTracker
from common.localization.tracking import track_model
from common.sim.objects import object_camera, rendered_object_flight, tabletop_model
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import Frame, PoseEstimate
from services.localizer import LocalizerService, LocalizerSettings
from services.localizer.filters import StepInputs
from services.localizer.loading import load_scene, localizer_camera
from services.runtime.camera_options import CameraOptions
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 16


def _settings(tmp_path: Path, start: tuple[float, ...]) -> LocalizerSettings:
    model = tabletop_model()
    lines = [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in model.vertices_world_m]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in model.faces]
    (tmp_path / "tabletop.obj").write_text("\n".join(lines) + "\n")
    (tmp_path / "camera.yaml").write_text(opencv_yaml_text(object_camera()))
    return LocalizerSettings(
        model=tmp_path / "tabletop.obj",
        camera=CameraOptions(calibration=tmp_path / "camera.yaml"),
        camera_mount="camera",
        initial_pose=start,
        seed=3,
    )


def test_frames_arriving_during_the_first_search_are_all_tracked_in_order(tmp_path: Path) -> None:
    flight, images = rendered_object_flight(N_FRAMES, 3, object_camera())
    rvec, tvec = flight.pose(0).rvec_tvec()
    settings = _settings(tmp_path, (*rvec.tolist(), *tvec.tolist()))
    tracker = ModelTracker(load_scene(settings), localizer_camera(settings), settings.tracker_settings())
    expected = list(
        track_model(
            tracker,
            images,
            flight.times_s,
            tracker.start(settings.start_pose()),
            np.random.default_rng(settings.seed),
        )
    )
    assert all(s.status.value == "tracking" for s in expected)  # so a catch-up never ends early here

    with hub() as endpoint:
        service = LocalizerService("test", 0, peer(endpoint), settings, stats_period_s=0.2)
        step = service.path.step
        first = threading.Event()

        def long_first_search(inputs: StepInputs) -> PoseEstimate:
            # the first frame's search lasts until every other frame has arrived (a slow search on a busy
            # host: over 0.5 s, here the whole stream)
            if not first.is_set():
                first.set()
                wait_until(lambda: service.counters.get("frames_in") == N_FRAMES)
            return step(inputs)

        service.path.step = long_first_search  # type: ignore[method-assign]
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
                assert matched(publisher) and matched(service._publisher)
                t0 = time.monotonic()
                for i, image in enumerate(images):  # at the flight's own rate (30 fps)
                    time.sleep(
                        max(0.0, float(flight.times_s[i] - flight.times_s[0]) - (time.monotonic() - t0))
                    )
                    frame = Frame(
                        uav="uav0",
                        seq=i,
                        stamp_s=float(flight.times_s[i]),
                        width=image.shape[1],
                        height=image.shape[0],
                        pixels=image,
                    )
                    payload, attachment = encode(frame)
                    publisher.put(payload, attachment=attachment)
                received = [poses.get(timeout=WAIT_S) for _ in range(N_FRAMES)]
                subscriber.undeclare()
                publisher.undeclare()
        finally:
            service.request_stop()
            runner.join(5.0)
    assert first.is_set()
    assert [p.seq for p in received] == list(range(N_FRAMES))
    for pose, state in zip(received, expected, strict=True):  # caught up with the stamps' intervals
        assert pose.tracking_state == "tracking"
        assert np.allclose(pose.p_world_body_m, state.pose.p_world_camera_m, atol=1e-9)
    counts = service.counters.counts()
    assert counts.get("dropped_frames", 0) == 0
    assert counts.get("backlog_overflow", 0) == 0
    assert counts.get("catch_ups") == 1
    assert counts.get("poses_out") == counts.get("frames_tracking") == N_FRAMES
