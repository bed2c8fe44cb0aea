"""The estimator service under hostile stamps and a busy host: future stamps refused and counted, each
output with its own covariance, SIGTERM while busy exits 0, paper C's flight ends within 2 cm with the cores
loaded."""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.estimation.measurements import ImuMeasurement
from common.estimation.replay import RECTIFIED_ORIGIN_DELAY_S
from common.sim.flight import Flight, turns_flight
from common.sim.stream import flight_measurements
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import AttitudeEstimate, Health, ImuSample, PoseEstimate, Stats
from services.estimator import EstimatorService, EstimatorSettings
from services.estimator.outputs import AS_FILTERED
from services.runtime.transport import TransportSettings, open_session, zbytes
from services.tools.bench import busy_loops
from services.tools.up import capataz_command
from tests.services.fakes import FakePublisher
from tests.services.publishing import publish_measurements
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

#: the two long runs under busy loops (about 4 minutes together) run on request
LOAD_RUNS = pytest.mark.skipif(
    not os.environ.get("CAPATAZ_LOAD_TESTS"), reason="long run under busy loops; CAPATAZ_LOAD_TESTS=1 runs it"
)


@pytest.fixture(scope="module")
def flight() -> Flight:
    return turns_flight(seed=0)


def settings_of(flight: Flight) -> EstimatorSettings:
    return EstimatorSettings(
        initial_yaw_rad=float(flight.yaw_rad[0]),
        initial_position_m=(float(flight.p_world_body_m[0, 0]), float(flight.p_world_body_m[0, 1])),
    )


@contextlib.contextmanager
def busy_host(n: int | None = None) -> Iterator[None]:
    """Busy-loop processes on every core for the duration (the test's own load; ``CAPATAZ_LOAD_BUSY=N`` runs
    N of them instead, e.g. twice the cores for a harsher run)."""
    with busy_loops(n or int(os.environ.get("CAPATAZ_LOAD_BUSY", "0")) or os.cpu_count() or 2):
        yield


def test_each_output_of_a_batch_carries_its_own_covariance(flight: Flight) -> None:
    """Regression (issue 9 section 5): the batch's last covariance was attached to every output of a batch."""
    service = EstimatorService("cov", 0, TransportSettings(), settings_of(flight))
    service._attitude_pub, service._pose_pub = FakePublisher(), FakePublisher()  # type: ignore[assignment]
    # the filter's covariances as they are: what the published model makes of each is test_estimator_outputs'
    service._publication.model = AS_FILTERED
    for m in flight_measurements(flight, 0, 6):
        service.estimator.push(m)
    outputs = service.estimator.process_due()  # one batch: many IMU steps and some frames
    attitudes = [o for o in outputs if isinstance(o, AttitudeOutput)]
    assert len(attitudes) > 50 and any(isinstance(o, PoseOutput) for o in outputs)
    service._publication.publish(outputs, service.publish, service._attitude_pub, service._pose_pub)
    published = [decode(p, a, AttitudeEstimate) for p, a in service._attitude_pub.puts]  # type: ignore[attr-defined]
    assert len(published) == len(attitudes)
    for msg, out in zip(published, attitudes, strict=True):
        np.testing.assert_allclose(msg.covariance, out.attitude_covariance_world, rtol=1e-12, atol=1e-18)
    assert not np.allclose(published[0].covariance, published[-1].covariance)


def _run_service(service: EstimatorService) -> threading.Thread:
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    assert service.started.wait(20.0), "service did not start"
    return runner


@pytest.mark.zenoh
def test_future_stamped_imu_is_refused_counted_and_the_filter_goes_on(flight: Flight) -> None:
    with hub() as endpoint:
        _future_stamps(flight, endpoint)


def _future_stamps(flight: Flight, endpoint: str) -> None:
    service = EstimatorService("future", 0, peer(endpoint), settings_of(flight))
    runner = _run_service(service)
    attitudes: queue.Queue[AttitudeEstimate] = queue.Queue()
    stream = list(flight_measurements(flight, 0, 40))
    try:
        with open_session(peer(endpoint)) as session:
            sub = session.declare_subscriber(
                keys.attitude_key("uav0"),
                lambda s: attitudes.put(decode(zbytes(s.payload), zbytes(s.attachment), AttitudeEstimate)),
            )
            probe = session.declare_publisher(
                keys.imu_key("uav0"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            assert matched(probe) and matched(service._attitude_pub)
            half = len(stream) // 2
            publish_measurements(session, "uav0", stream[:half], speed=1.0, block=True)
            for _ in range(2):  # two samples 1e5 s in the future
                payload, attachment = encode(
                    ImuSample(uav="uav0", stamp_s=stream[half].stamp_s + 1e5, gyro_rad_s=np.zeros(3),
                              accel_m_s2=np.array([0.0, 0.0, 9.8]))
                )  # fmt: skip
                probe.put(payload, attachment=attachment)
            publish_measurements(session, "uav0", stream[half:], speed=1.0, block=True, first_seq=half)
            t_end = stream[-1].stamp_s
            deadline = time.monotonic() + 20.0
            newest = 0.0
            while newest < t_end - 0.1 and time.monotonic() < deadline:
                with contextlib.suppress(queue.Empty):
                    newest = max(newest, attitudes.get(timeout=0.5).stamp_s)
            ok, detail = service.healthy()
            sub.undeclare()
            probe.undeclare()
    finally:
        service.request_stop()
        runner.join(5.0)
    counts = service.counters.counts()
    assert counts.get("refused_imu_stamp_jump") == 2, counts
    assert not any(k.startswith("refused_camera") or k.startswith("epochs_") for k in counts), counts
    assert newest >= t_end - 0.1, f"the filter stopped at {newest} (stream ends {t_end}); {counts}"
    assert not any(k.startswith("refused_imu_stale") for k in counts), counts
    assert not ok and "refused" in detail


@pytest.mark.zenoh
@pytest.mark.slow
@LOAD_RUNS
def test_sigterm_while_busy_exits_0_twenty_times_in_twenty(flight: Flight) -> None:
    stream = list(flight_measurements(flight, 0, 60))
    codes = []
    with busy_host(), hub() as endpoint:
        for attempt in range(20):
            process = subprocess.Popen(
                capataz_command("estimator", "--connect", endpoint, "--listen", "tcp/127.0.0.1:0",
                                "--no-multicast", "--no-shm"),
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            )  # fmt: skip
            try:
                with open_session(peer(endpoint)) as session:
                    probe = session.declare_publisher(keys.imu_key("uav0"))
                    assert matched(probe, 60.0), "the estimator did not come up"
                    probe.undeclare()
                    sender = threading.Thread(
                        target=publish_measurements, args=(session, "uav0", stream), kwargs={"speed": 0.0}
                    )
                    sender.start()
                    time.sleep(0.2 + 0.05 * (attempt % 5))  # SIGTERM while samples and frames pour in
                    process.send_signal(signal.SIGTERM)
                    sender.join(WAIT_S)
                code = process.wait(WAIT_S)
            finally:
                if process.poll() is None:
                    process.kill()
            stderr = process.stderr.read().decode() if process.stderr else ""
            assert "Traceback" not in stderr, stderr[-2000:]
            codes.append(code)
    assert codes == [0] * 20, codes


@pytest.mark.zenoh
@pytest.mark.slow
@LOAD_RUNS
def test_paper_c_flight_under_a_busy_host_ends_within_2_cm(flight: Flight) -> None:
    """As the bench's ``rectified_any_vehicle`` run, the service's defaults (VO origin 4 s in, at the true
    position then): 0.71 cm offline (the bench's ``rectified``, a still-air multirotor: 0.02 cm). The
    service runs as deployed, in its own process (``capataz estimator``); its counters and health are read
    over Zenoh, as an operator would."""
    origin = int(
        np.searchsorted(flight.frame_stamps_s, flight.frame_stamps_s[0] + RECTIFIED_ORIGIN_DELAY_S - 1e-9)
    )
    x0, y0 = (f"{v:.17g}" for v in flight.p_world_body_m[origin, :2])
    stream = list(flight_measurements(flight))
    poses: list[PoseEstimate] = []
    stats: list[Stats] = []
    verdicts: list[Health] = []  # health while it runs
    with busy_host(), hub(lease_ms=2000) as endpoint:
        process = subprocess.Popen(
            capataz_command("estimator", "--node", "busy", "--connect", endpoint,
                            "--listen", "tcp/127.0.0.1:0", "--no-multicast", "--no-shm",
                            "--lease-ms", "2000", "--stats-period", "0.5",
                            "--initial-yaw", f"{flight.yaw_rad[0]:.17g}", "--initial-xy", x0, y0,
                            "--vo-origin-delay", str(RECTIFIED_ORIGIN_DELAY_S)),
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        )  # fmt: skip
        done = threading.Event()
        try:
            with open_session(peer(endpoint, lease_ms=2000)) as session:
                subs = [
                    session.declare_subscriber(
                        keys.pose_vo_key("uav0"),
                        lambda s: poses.append(decode(zbytes(s.payload), zbytes(s.attachment), PoseEstimate)),
                    ),
                    session.declare_subscriber(
                        keys.stats_key("estimator", "busy", 0),
                        lambda s: stats.append(decode(zbytes(s.payload), zbytes(s.attachment), Stats)),
                    ),
                ]
                probes = [session.declare_publisher(key("uav0")) for key in (keys.imu_key, keys.camera_key)]
                assert all(matched(p, 60.0) for p in probes), "the estimator did not come up"
                assert wait_until(lambda: bool(stats), 60.0), "no stats from the estimator"

                def watch_health() -> None:
                    while not done.wait(0.5):
                        for reply in session.get(keys.health_key("estimator", "busy", 0), timeout=5.0):
                            if reply.ok is not None:
                                sample = reply.ok
                                verdicts.append(
                                    decode(zbytes(sample.payload), zbytes(sample.attachment), Health)
                                )

                watcher = threading.Thread(target=watch_health, daemon=True)
                watcher.start()
                publish_measurements(session, "uav0", stream, speed=1.0, block=True)
                wait_until(lambda: bool(poses) and poses[-1].stamp_s >= stream[-1].stamp_s - 0.06)
                last_stats = len(stats)
                wait_until(lambda: len(stats) > last_stats + 1)  # counters after the last pose
                done.set()
                watcher.join(WAIT_S)
                for sub in subs:
                    sub.undeclare()
            process.send_signal(signal.SIGTERM)
            code = process.wait(WAIT_S)
        finally:
            done.set()
            if process.poll() is None:
                process.kill()
                process.wait()
    stderr = process.stderr.read().decode() if process.stderr else ""
    counts = stats[-1].counters
    last = poses[-1]
    k = int(np.argmin(np.abs(flight.frame_stamps_s - last.stamp_s)))
    error_m = float(np.linalg.norm(last.p_world_body_m[:2] - flight.p_world_body_m[k, :2]))
    spacings = {name: n for name, n in counts.items() if name.startswith("vo_spacing_")}
    print(
        f"busy host: final VO error {100 * error_m:.2f} cm at frame {k} (reported sigma "
        f"{100 * np.sqrt(last.covariance[0, 0]):.2f} cm, {last.tracking_state}); frames used "
        f"{counts.get('frames_used')} of {counts.get('frames_in')}, pair spacings {spacings}; "
        f"counters {counts}; deepest queues "
        f"{ {q: max(s.queue_depths.get(q, 0) for s in stats) for q in stats[-1].queue_depths} }"
    )
    assert code == 0 and "Traceback" not in stderr, stderr[-2000:]
    assert k >= flight.n_frames - 3
    n_imu = sum(isinstance(m, ImuMeasurement) for m in stream)
    # IMU is never dropped for frames, nor range refused because the queue is behind
    assert counts.get("imu_applied", 0) >= n_imu - 10, counts
    assert not any(name.startswith("refused_") or name == "queue_full" for name in counts), counts
    # every frame accounted for: used by the VO or skipped (counted, with health degraded meanwhile)
    assert (
        counts.get("frames_used", 0) + counts.get("frames_skipped", 0)
        == counts.get("frames_in")
        == len(flight.frame_stamps_s)
    ), counts
    if counts.get("frames_skipped", 0):
        assert any(not h.ok and "behind" in h.detail for h in verdicts), [h.detail for h in verdicts[-5:]]
    # a pose is "lost" only where its VO pair failed (the position not measured), else "tracking"
    lost = sum(p.tracking_state == "lost" for p in poses)
    assert {p.tracking_state for p in poses} <= {"tracking", "lost"}
    assert lost <= counts.get("vo_failures", 0), (lost, counts)
    assert error_m <= 0.02, f"{100 * error_m:.2f} cm; {counts}"
