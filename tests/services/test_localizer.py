"""The localizer service over Zenoh on loopback: the same poses as the in-process filter, and it survives
malformed, foreign, wrong-size and stale frames (refused and counted)."""

from __future__ import annotations

import queue
import threading
from typing import Any

import numpy as np
import pytest

from common import keys
from common.geometry import quaternion_from_euler
from common.localization.particle_filter import ParticleFilter, ParticleFilterSettings
from common.localization.scoring import ScoringMethod, ScoringSettings
from common.localization.simulation import simulate_run
from common.localization.tracking import localizer_step
from common.messages import Frame, PoseEstimate, decode, encode
from services.localizer import LocalizerService, LocalizerSettings
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 12
PARTICLES = 60
SEED = 5


def _frame(seq: int, stamp_s: float, pixels: np.ndarray, uav: str = "uav0") -> Frame:
    return Frame(
        uav=uav, seq=seq, stamp_s=stamp_s, width=pixels.shape[1], height=pixels.shape[0], pixels=pixels
    )


def test_service_publishes_the_in_process_poses_and_survives_bad_frames() -> None:
    sim = simulate_run(n_frames=N_FRAMES, seed=2)
    settings = LocalizerSettings(
        particles=PARTICLES,
        scoring=ScoringMethod.NEAREST_EDGE_DT,
        seed=SEED,
        initial_pose=tuple(float(v) for v in sim.guess),  # type: ignore[arg-type]
    )
    # the in-process reference: same scene, camera, settings and seed
    pf = ParticleFilter(
        sim.scene,
        sim.camera,
        ParticleFilterSettings(n_particles=PARTICLES, scoring=ScoringSettings(ScoringMethod.NEAREST_EDGE_DT)),
    )
    rng = np.random.default_rng(SEED)
    state = pf.initialize(sim.guess, rng)
    expected = []
    for i, image in enumerate(sim.images):
        dt = 0.0 if i == 0 else float(sim.flight.times_s[i] - sim.flight.times_s[i - 1])
        state, estimate = localizer_step(pf, state, image, dt, rng)
        expected.append(estimate)

    with hub() as endpoint:
        service, received = _run_the_service(sim, settings, endpoint)
    assert [p.seq for p in received] == list(range(N_FRAMES))
    for pose, estimate in zip(received, expected, strict=True):
        assert pose.source == "pf"
        assert np.allclose(pose.p_world_body_m, estimate.mean[:3], atol=1e-9)
        assert np.allclose(pose.q_world_body, quaternion_from_euler(*estimate.mean[3:]), atol=1e-9)
        assert np.all(np.linalg.eigvalsh(pose.covariance) >= -1e-12)
    counts = service.counters.counts()
    assert counts.get("malformed") == 1
    assert counts.get("wrong_uav") == 1
    assert counts.get("bad_frames") == 1
    assert counts.get("stale_frames") == 1
    assert counts.get("poses_out") == N_FRAMES
    assert counts.get("thread_crashes", 0) == 0


def _run_the_service(
    sim: Any, settings: LocalizerSettings, endpoint: str
) -> tuple[LocalizerService, list[PoseEstimate]]:
    service = LocalizerService("test", 0, peer(endpoint), settings, stats_period_s=0.2)
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

            def put(message: Frame) -> None:
                payload, attachment = encode(message)
                publisher.put(payload, attachment=attachment)

            received: list[PoseEstimate] = []
            for i, image in enumerate(sim.images):
                stamp = float(sim.flight.times_s[i])
                if i == 3:  # garbage, another UAV's frame, a wrong size, a stale stamp: all refused
                    publisher.put(b"\x00garbage", attachment=b"\x93not-a-header")
                    put(_frame(99, stamp, image, uav="uav7"))
                    put(_frame(99, stamp, np.zeros((10, 12), dtype=np.uint8)))
                    put(_frame(99, float(sim.flight.times_s[i - 1]), image))
                put(_frame(i, stamp, image))
                received.append(poses.get(timeout=WAIT_S))  # one frame in flight: nothing dropped

            def all_refused() -> bool:
                counts = service.counters.counts()
                return (
                    sum(counts.get(k, 0) for k in ("malformed", "wrong_uav", "bad_frames", "stale_frames"))
                    >= 4
                )

            assert wait_until(all_refused), service.counters.counts()
            assert poses.empty(), "a refused frame produced a pose"
            subscriber.undeclare()
            publisher.undeclare()
    finally:
        service.request_stop()
        runner.join(5.0)
    assert not runner.is_alive()
    return service, received
