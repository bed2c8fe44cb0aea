"""``capataz estimator`` over Zenoh on loopback: it publishes the in-process estimates for a simulated
stream of flight (b), and survives a burst of malformed samples (garbage, NaN, another UAV's, wrong size,
stale) with its counters showing them."""

from __future__ import annotations

import queue
import threading
import time
from typing import Any

import numpy as np
import pytest
import zenoh

from common import keys
from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.estimation.replay import flight_measurements
from common.messages import AttitudeEstimate, Frame, ImuSample, PoseEstimate, RangeSample, decode, encode
from common.sim.flight import Flight, turns_flight
from services.estimator import EstimatorService, EstimatorSettings, build_estimator
from services.estimator.sim_publisher import publish_measurements
from services.runtime.transport import TransportSettings, open_session, zbytes
from services.up import free_port

pytestmark = pytest.mark.zenoh

N_FRAMES = 24


def _matching(publisher: Any) -> bool:
    return bool(publisher.matching_status.matching)


@pytest.fixture(scope="module")
def flight() -> Flight:
    return turns_flight(seed=0)


def test_service_matches_in_process_run_and_survives_malformed_samples(flight: Flight) -> None:
    settings = EstimatorSettings(
        initial_yaw_rad=float(flight.yaw_rad[0]),
        initial_x_m=float(flight.p_world_body_m[0, 0]),
        initial_y_m=float(flight.p_world_body_m[0, 1]),
    )
    stream = list(flight_measurements(flight, 0, N_FRAMES))
    reference = build_estimator(settings)
    expected: list[AttitudeOutput | PoseOutput] = []
    for m in stream:
        reference.push(m)
        expected.extend(reference.process_due())
    expected.extend(reference.drain())
    expected_att = [o for o in expected if isinstance(o, AttitudeOutput)]
    expected_pose = [o for o in expected if isinstance(o, PoseOutput)]

    port = free_port()
    service = EstimatorService(
        "test",
        0,
        TransportSettings(listen=(f"tcp/127.0.0.1:{port}",), lease_ms=1000),
        settings,
        stats_period_s=0.2,
    )
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    attitudes: queue.Queue[AttitudeEstimate] = queue.Queue()
    poses: queue.Queue[PoseEstimate] = queue.Queue()
    client = TransportSettings(listen=("tcp/127.0.0.1:0",), connect=(f"tcp/127.0.0.1:{port}",))
    try:
        assert service.started.wait(20.0), "service did not start"
        with open_session(client) as session:
            subs = [
                session.declare_subscriber(
                    keys.attitude_key("uav0"),
                    lambda s: attitudes.put(
                        decode(zbytes(s.payload), zbytes(s.attachment), AttitudeEstimate)
                    ),
                ),
                session.declare_subscriber(
                    keys.pose_vo_key("uav0"),
                    lambda s: poses.put(decode(zbytes(s.payload), zbytes(s.attachment), PoseEstimate)),
                ),
            ]
            probe = session.declare_publisher(
                keys.imu_key("uav0"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            deadline = time.monotonic() + 10.0
            while not _matching(probe) and time.monotonic() < deadline:
                time.sleep(0.02)
            assert _matching(probe)
            time.sleep(0.3)  # the other subscribers of the service are declared together with this one
            assert publish_measurements(session, "uav0", stream, speed=0.5, block=True) == len(stream)

            # the end of the stream is held back by the reordering lag: push it out with later IMU samples
            t_end = stream[-1].stamp_s
            imu = flight.imu
            tail = [
                (float(t), g, a)
                for t, g, a in zip(imu.stamps_s, imu.gyro_rad_s, imu.accel_m_s2, strict=True)
                if t_end < t <= t_end + 0.1
            ]

            def put_imu(stamp: float, gyro: np.ndarray, accel: np.ndarray, uav: str = "uav0") -> None:
                payload, attachment = encode(
                    ImuSample(uav=uav, stamp_s=stamp, gyro_rad_s=gyro, accel_m_s2=accel)
                )
                probe.put(payload, attachment=attachment)

            for t, g, a in tail[:20]:
                put_imu(t, g, a)
            received_att = []
            try:
                for _ in range(len(expected_att)):
                    received_att.append(attitudes.get(timeout=20.0))
            except queue.Empty:
                raise AssertionError(
                    f"{len(received_att)} of {len(expected_att)} attitudes; {service.counters.counts()}"
                ) from None
            received_pose = [poses.get(timeout=20.0) for _ in range(len(expected_pose))]

            # a burst of bad samples: garbage, NaN, another UAV's, wrong frame size, stale stamps
            nan_payload, nan_header = encode(
                ImuSample(uav="uav0", stamp_s=t_end + 0.2, gyro_rad_s=np.zeros(3), accel_m_s2=np.zeros(3))
            )
            nan_payload = np.array([np.nan, 0.0, 0.0, 0.0, 0.0, 9.8]).tobytes()
            camera = session.declare_publisher(keys.camera_key("uav0"))
            ranger = session.declare_publisher(keys.range_key("uav0"))
            for _ in range(5):
                probe.put(b"\x00garbage", attachment=b"\x93not-a-header")
            probe.put(nan_payload, attachment=nan_header)
            put_imu(t_end + 0.2, np.zeros(3), np.array([0.0, 0.0, 9.8]), uav="uav7")
            put_imu(1.0, np.zeros(3), np.array([0.0, 0.0, 9.8]))  # long released: stale
            payload, attachment = encode(
                Frame(
                    uav="uav0",
                    seq=0,
                    stamp_s=t_end + 0.2,
                    width=12,
                    height=10,
                    pixels=np.zeros((10, 12), np.uint8),
                )
            )
            camera.put(payload, attachment=attachment)
            payload, attachment = encode(
                RangeSample(uav="uav0", stamp_s=float(flight.range.stamps_s[3]), range_m=3.5)
            )
            ranger.put(payload, attachment=attachment)  # a stamp long applied: stale
            # still alive: the rest of the tail goes through
            for t, g, a in tail[20:]:
                put_imu(t, g, a)
            after = attitudes.get(timeout=20.0)
            time.sleep(0.5)
            for sub in subs:
                sub.undeclare()
            for publisher in (probe, camera, ranger):
                publisher.undeclare()
    finally:
        service.request_stop()
        runner.join(5.0)
    assert not runner.is_alive()

    assert [a.stamp_s for a in received_att] == [o.stamp_s for o in expected_att]
    for att, att_out in zip(received_att, expected_att, strict=True):
        assert np.allclose(att.q_world_body, att_out.q_world_body, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(att.covariance) >= -1e-15)
    assert [p.stamp_s for p in received_pose] == [o.stamp_s for o in expected_pose]
    for msg, out in zip(received_pose, expected_pose, strict=True):
        assert msg.source == "vo"
        assert np.allclose(msg.p_world_body_m, out.p_world_body_m, atol=1e-12)
    assert after.stamp_s > t_end

    counts = service.counters.counts()
    assert counts.get("malformed", 0) >= 6  # 5 garbage + the NaN sample (refused at decode or at the check)
    assert counts.get("malformed", 0) + counts.get("bad_samples", 0) == 6
    assert counts.get("wrong_uav") == 1
    assert counts.get("bad_frames") == 1
    assert counts.get("refused_imu_stale") == 1
    assert counts.get("refused_range_stale") == 1
    assert counts.get("dropped_frames", 0) == 0
    assert counts.get("poses_out") == N_FRAMES
    assert counts.get("thread_crashes", 0) == 0


class _RecordingEstimator(EstimatorService):
    """Records the stamps of the samples its callbacks see, in the order they see them."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.seen: list[float] = []

    def _on_imu(self, sample: zenoh.Sample) -> None:
        self.seen.append(decode(zbytes(sample.payload), zbytes(sample.attachment), ImuSample).stamp_s)
        super()._on_imu(sample)

    def _on_range(self, sample: zenoh.Sample) -> None:
        self.seen.append(decode(zbytes(sample.payload), zbytes(sample.attachment), RangeSample).stamp_s)
        super()._on_range(sample)

    def _on_frame(self, sample: zenoh.Sample) -> None:
        self.seen.append(decode(zbytes(sample.payload), zbytes(sample.attachment), Frame).stamp_s)
        super()._on_frame(sample)


def test_sensor_samples_are_handed_off_in_the_order_they_were_published(flight: Flight) -> None:
    """Regression: each subscriber had its own Python thread, so a frame (360 KB to decode) could reach the
    time-ordered buffer after IMU samples published after it, more than the lag newer, and be refused as stale
    (the service test above failed so under CPU load). The callbacks now run in arrival order."""
    settings = EstimatorSettings(
        initial_yaw_rad=float(flight.yaw_rad[0]),
        initial_x_m=float(flight.p_world_body_m[0, 0]),
        initial_y_m=float(flight.p_world_body_m[0, 1]),
    )
    burst = list(flight_measurements(flight, 0, 8))
    port = free_port()
    service = _RecordingEstimator(
        "burst", 0, TransportSettings(listen=(f"tcp/127.0.0.1:{port}",), lease_ms=1000), settings
    )
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    client = TransportSettings(listen=("tcp/127.0.0.1:0",), connect=(f"tcp/127.0.0.1:{port}",))
    try:
        assert service.started.wait(20.0), "service did not start"
        with open_session(client) as session:
            probe = session.declare_publisher(keys.imu_key("uav0"))
            deadline = time.monotonic() + 10.0
            while not _matching(probe) and time.monotonic() < deadline:
                time.sleep(0.02)
            probe.undeclare()
            time.sleep(0.3)  # the camera and range subscribers are declared with the IMU's
            assert publish_measurements(session, "uav0", burst, speed=0.0, block=True) == len(burst)
            deadline = time.monotonic() + 20.0
            while len(service.seen) < len(burst) and time.monotonic() < deadline:
                time.sleep(0.05)
    finally:
        service.request_stop()
        runner.join(5.0)
    assert service.seen == [m.stamp_s for m in burst]
    assert service.counters.get("refused_frame_stale") == 0
