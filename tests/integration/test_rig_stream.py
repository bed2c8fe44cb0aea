"""The rig travels with the stream (issue 26): ``capataz camera`` replaying an image folder with a calibration
file alone gives the master its lens (the published yaw equals the in-process core told the same rig); a frame
naming a rig the master never received is refused and counted; a rig changed mid-stream is picked up."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh

from common.camera import CameraModel, Distortion, DistortionModel
from common.datasets.rig_files import write_rig
from common.provenance import Provenance
from common.rig import Rig
from common.sim.field import field_flight
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Frame, YawEstimate
from common.wire.rig import message_of_rig
from common.yaw import YawSettings, YawTracker, make_patch_grid
from services.camera import CameraService, CameraSettings
from services.master import MasterService, MasterSettings
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, put_message, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 8


@pytest.fixture
def endpoint() -> Iterator[str]:
    with hub() as value:
        yield value


def _run(service: MasterService | CameraService) -> threading.Thread:
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    return thread


class _Yaws:
    def __init__(self, session: zenoh.Session) -> None:
        self.received: list[YawEstimate] = []
        self.subscriber = session.declare_subscriber(keys.yaw_key("uav0"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        self.received.append(decode(zbytes(sample.payload), zbytes(sample.attachment), YawEstimate))


def test_an_image_folder_and_its_calibration_give_the_master_its_lens(endpoint: str, tmp_path: Path) -> None:
    flight = field_flight("wide_angle", seed=0, n_frames=N_FRAMES)  # 320x240, strong barrel distortion
    frames = list(flight.frames())
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, image in enumerate(frames):
        cv2.imwrite(str(folder / f"{k:04d}.png"), image)
    stamps = tmp_path / "stamps.csv"
    stamps.write_text("".join(f"{k},{t:.9f}\n" for k, t in enumerate(flight.frame_stamps_s[:N_FRAMES])))
    rig = Rig(flight.camera, flight.R_body_camera)
    rig_file = write_rig(rig, tmp_path / "rig.yaml")
    # the in-process core told the same rig, on the same frames and stamps (no gyro: the folder has no IMU)
    settings = YawSettings(camera=rig.camera)
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings), rig.R_body_camera)
    state = tracker.initial_state(frames[0], stamp_s=float(flight.frame_stamps_s[0]))
    expected = []
    for k in range(1, N_FRAMES):
        state, estimate = tracker.track(state, frames[k], float(flight.frame_stamps_s[k]))
        expected.append(estimate.yaw_rad)

    master = MasterService("m", 0, peer(endpoint), MasterSettings(election=False))
    camera = CameraService(
        "c", 0, peer(endpoint),
        CameraSettings(images=folder, stamps=stamps, calibration=rig_file, fps=0.0, in_flight=1),
    )  # fmt: skip
    threads = [_run(master)]
    with open_session(peer(endpoint)) as session:
        yaws = _Yaws(session)
        assert master.started.wait(WAIT_S)
        threads.append(_run(camera))
        # every measured frame's yaw (the first frame's INITIAL one may pass before the observer is routed)
        wanted = set(range(1, N_FRAMES))
        assert wait_until(lambda: wanted <= {e.seq for e in yaws.received}, 60.0), len(yaws.received)
    for service in (camera, master):
        service.request_stop()
    for thread in threads:
        thread.join(10.0)
    assert master.counters.get("rigs_received") == 1 and not master.counters.get("refused_camera_unknown_rig")
    by_seq = {e.seq: e for e in yaws.received}
    assert all(by_seq[k].provenance is not Provenance.INITIAL for k in wanted)
    assert np.allclose([by_seq[k].yaw_rad for k in sorted(wanted)], expected, atol=1e-9)


def _stream_rig(fx: float) -> Rig:
    camera = CameraModel(
        width=752, height=480, fx=fx, fy=fx, cx=375.5, cy=239.5,
        distortion=Distortion(DistortionModel.RADTAN, (-0.05, 0.01, 0.0, 0.0, 0.0)),
    )  # fmt: skip
    return Rig(camera)


def test_an_unknown_rig_is_refused_and_a_changed_rig_is_picked_up_continuing_the_yaw_variance_regression(
    endpoint: str,
) -> None:
    """The regression: a new stream (a changed rig, a new epoch, a take-over) continued the yaw but started
    its variance over at 0, publishing a yaw many frames old as if it were exact."""
    master = MasterService("m", 0, peer(endpoint), MasterSettings(election=False))
    thread = _run(master)
    flight = field_flight("wide_angle", seed=1, n_frames=2)  # only for a textured frame
    pixels = cv2.resize(flight.frame(0), (752, 480))
    first, second = _stream_rig(376.0), _stream_rig(400.0)
    try:
        assert master.started.wait(WAIT_S)
        with open_session(peer(endpoint)) as session:
            yaws = _Yaws(session)
            frames = session.declare_publisher(keys.camera_key("uav0"))
            rigs = session.declare_publisher(keys.rig_key("uav0"))
            assert matched(frames) and matched(rigs)
            seq = 0

            def send(rig: Rig | None, rig_id: str | None = None) -> None:
                nonlocal seq
                frame = Frame(uav="uav0", seq=seq, stamp_s=time.time(), width=752, height=480, pixels=pixels,
                              rig_id=rig.rig_id if rig is not None else rig_id)  # fmt: skip
                put_message(frames, frame)
                seq += 1

            send(None, rig_id="0123456789abcdef")  # a rig never published: refused, counted
            assert wait_until(lambda: master.counters.get("refused_camera_unknown_rig") == 1)
            put_message(rigs, message_of_rig("uav0", first, time.time()))
            assert wait_until(lambda: master.counters.get("rigs_received") == 1)
            # one frame at a time: the master keeps the latest frame only, and a busy host could skip one
            for k in range(1, 4):
                send(first)
                assert wait_until(lambda k=k: len(yaws.received) == k)
            put_message(rigs, message_of_rig("uav0", second, time.time()))
            assert wait_until(lambda: master.counters.get("rigs_received") == 2)
            for k in range(4, 7):
                send(second)
                assert wait_until(lambda k=k: len(yaws.received) == k)
    finally:
        master.request_stop()
        thread.join(10.0)
    estimates = sorted(yaws.received, key=lambda e: e.seq)
    provenance = [e.provenance for e in estimates]
    # each rig starts a stream of its own (measured with its lens), the yaw continuing across
    assert provenance[0] is Provenance.INITIAL and provenance[3] is Provenance.INITIAL
    # ... and its variance: it never shrinks, and the second rig's first yaw is the first rig's last
    variances = [e.yaw_variance_rad2 for e in estimates]
    assert variances[2] > 0.0 and variances[3] == variances[2]
    assert all(later >= earlier for earlier, later in itertools.pairwise(variances))
    assert Provenance.INITIAL not in (provenance[1], provenance[2], provenance[4], provenance[5])
    assert master.counters.get("refused_camera_unknown_rig") == 1
