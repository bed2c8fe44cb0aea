"""``capataz estimator`` over Zenoh on loopback: it publishes the in-process estimates for a simulated
stream of flight (b), and survives a burst of malformed samples (garbage, NaN, another UAV's, wrong size,
stale) with its counters showing them."""

from __future__ import annotations

import queue
import threading
from typing import Any

import numpy as np
import pytest
import zenoh

from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.sim.flight import Flight, turns_flight
from common.sim.stream import flight_measurements
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.measurements import message_of
from common.wire.messages import AttitudeEstimate, Frame, ImuSample, PoseEstimate, RangeSample
from services.estimator import EstimatorService, EstimatorSettings, build_estimator
from services.runtime.transport import open_session, zbytes
from tests.services.publishing import publish_measurements
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 24


@pytest.fixture(scope="module")
def flight() -> Flight:
    return turns_flight(seed=0)


def test_service_matches_in_process_run_and_survives_malformed_samples(flight: Flight) -> None:
    with hub() as endpoint:
        _matches_in_process_run_and_survives_malformed_samples(flight, endpoint)


def _matches_in_process_run_and_survives_malformed_samples(flight: Flight, endpoint: str) -> None:
    settings = EstimatorSettings(
        initial_yaw_rad=float(flight.yaw_rad[0]),
        initial_position_m=(float(flight.p_world_body_m[0, 0]), float(flight.p_world_body_m[0, 1])),
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

    service = EstimatorService("test", 0, peer(endpoint), settings, stats_period_s=0.2)
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    attitudes: queue.Queue[AttitudeEstimate] = queue.Queue()
    poses: queue.Queue[PoseEstimate] = queue.Queue()
    try:
        assert service.started.wait(WAIT_S), "service did not start"
        with open_session(peer(endpoint)) as session:
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
            block = zenoh.CongestionControl.BLOCK
            camera = session.declare_publisher(keys.camera_key("uav0"), congestion_control=block)
            ranger = session.declare_publisher(keys.range_key("uav0"), congestion_control=block)
            # every subscriber of the service is routed (and it sees ours): nothing published is lost
            assert all(matched(p) for p in (probe, camera, ranger, service._attitude_pub, service._pose_pub))
            # in stamp order, with flow control instead of a pace: a frame goes out once the previous one has
            # reached the estimator's thread (its latest-wins slot would drop it on a busy host otherwise)
            publishers = {p.key_expr: p for p in (probe, camera, ranger)}
            frames_sent = 0
            for seq, measurement in enumerate(stream):
                key, message = message_of("uav0", seq, measurement)
                if isinstance(message, Frame):

                    def taken(n: int = frames_sent) -> bool:
                        return service.counters.get("frames_in") == n and service._backlog.frames.depth() == 0

                    assert wait_until(taken), service.counters.counts()
                    frames_sent += 1
                payload, attachment = encode(message)
                publishers[zenoh.KeyExpr(key)].put(payload, attachment=attachment)

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
                    received_att.append(attitudes.get(timeout=WAIT_S))
            except queue.Empty:
                raise AssertionError(
                    f"{len(received_att)} of {len(expected_att)} attitudes; {service.counters.counts()}"
                ) from None
            received_pose = [poses.get(timeout=WAIT_S) for _ in range(len(expected_pose))]

            # a burst of bad samples: garbage, NaN, another UAV's, wrong frame size, stale stamps
            nan_payload, nan_header = encode(
                ImuSample(uav="uav0", stamp_s=t_end + 0.2, gyro_rad_s=np.zeros(3), accel_m_s2=np.zeros(3))
            )
            nan_payload = np.array([np.nan, 0.0, 0.0, 0.0, 0.0, 9.8]).tobytes()
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
            after = attitudes.get(timeout=WAIT_S)

            def refusals_counted() -> bool:  # the bad samples reach the service on its own threads
                c = service.counters.counts()
                return (
                    c.get("malformed", 0) + c.get("bad_samples", 0) >= 6
                    and all(c.get(k, 0) >= 1 for k in GATE_REFUSALS)
                    and c.get("poses_out", 0) >= N_FRAMES
                )

            assert wait_until(refusals_counted), service.counters.counts()
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
    assert all(counts.get(k) == 1 for k in GATE_REFUSALS), counts
    assert counts.get("frames_skipped", 0) == 0 and counts.get("frames_used") == N_FRAMES
    assert counts.get("poses_out") == N_FRAMES
    assert counts.get("thread_crashes", 0) == 0


#: what the input gate refused of the burst: another UAV's IMU sample, a frame of another size, an IMU and a
#: range sample stamped before ones already admitted
GATE_REFUSALS = (
    "refused_imu_foreign_uav",
    "refused_camera_wrong_size",
    "refused_imu_stamp_backward",
    "refused_range_stamp_backward",
)


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
        initial_position_m=(float(flight.p_world_body_m[0, 0]), float(flight.p_world_body_m[0, 1])),
    )
    burst = list(flight_measurements(flight, 0, 8))
    with hub() as endpoint:
        service = _RecordingEstimator("burst", 0, peer(endpoint), settings)
        runner = threading.Thread(target=service.run, daemon=True)
        runner.start()
        try:
            assert service.started.wait(WAIT_S), "service did not start"
            with open_session(peer(endpoint)) as session:
                probes = [
                    session.declare_publisher(key("uav0"))
                    for key in (keys.imu_key, keys.camera_key, keys.range_key)
                ]
                assert all(matched(p) for p in probes)  # each of the service's subscribers is routed
                for probe in probes:
                    probe.undeclare()
                assert publish_measurements(session, "uav0", burst, speed=0.0, block=True) == len(burst)
                assert wait_until(lambda: len(service.seen) >= len(burst))
        finally:
            service.request_stop()
            runner.join(5.0)
    assert service.seen == [m.stamp_s for m in burst]
    assert service.counters.get("refused_frame_stale") == 0
