"""The whole system under the secure profile (mutual TLS + access control on every participant): the yaw
cluster, the estimator (uav0) and the localizer (uav1, office flight) give the results of the open profile.

Yaw: equal to the in-process tracker frame by frame (flow-controlled camera, as the open cluster tests);
localizer: ``pose/pf`` within the open test's 10 cm of the truth at the end; estimator: attitude and
``pose/vo`` published for uav0. Every participant holds only its own role's certificate.
"""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from common import keys
from common.codec import decode
from common.messages import AttitudeEstimate, PoseEstimate
from common.sim.scene import default_flight
from common.wire import WireError
from services.bench import hostile
from services.runtime.transport import open_session, zbytes
from services.secure import SecureProfile
from services.up import LocalCluster
from tests.integration.cluster_helpers import two_by_two

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

FRAMES = 80


class Inbox:
    def __init__(self, session: zenoh.Session, key: str, expected: type) -> None:
        self.messages: list = []
        self.malformed = 0
        self._lock = threading.Lock()
        self._expected = expected
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            message = decode(zbytes(sample.payload), zbytes(sample.attachment), self._expected)
        except WireError:
            self.malformed += 1
            return
        with self._lock:
            self.messages.append(message)

    def snapshot(self) -> list:
        with self._lock:
            return list(self.messages)


def test_cluster_estimator_and_localizer_run_secure_with_the_open_results(tmp_path: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (needed to make the development certificates)")
    secure = SecureProfile.ensure(tmp_path / "secure")
    reference = hostile.reference_yaw_rad(FRAMES)
    with LocalCluster(two_by_two(workers=1), tmp_path / "logs", secure=secure) as cluster:
        cluster.start()
        transport = cluster.transport_args()
        cluster.spawn(
            "estimator/estimator/0",
            ["estimator", *transport, "--node", "estimator", "--uav", "uav0", "--external-yaw"],
        )
        cluster.spawn(
            "localizer/localizer/0",
            ["localizer", *transport, "--node", "localizer", "--uav", "uav1", "--use-vo"],
            common_name="localizer.uav1",
        )
        cluster.wait_alive(cluster.expected_members() | {"estimator/estimator/0", "localizer/localizer/0"})
        with open_session(cluster.observer_transport()) as session:
            watch = hostile.YawWatch(session, "uav0")
            attitude = Inbox(session, keys.attitude_key("uav0"), AttitudeEstimate)
            vo = Inbox(session, keys.pose_vo_key("uav0"), PoseEstimate)
            pf = Inbox(session, keys.pose_pf_key("uav1"), PoseEstimate)
            time.sleep(0.5)
            office = cluster.spawn(
                "camera/office/0",
                [
                    "camera", *transport, "--node", "office", "--uav", "uav1", "--flight", "office",
                    "--frames", str(FRAMES), "--fps", "10", "--wait-master", "0",
                ],
                common_name="camera.uav1",
            )  # fmt: skip
            hostile.fly(cluster, watch, FRAMES, fps=10.0, timeout_s=120.0, in_flight=1, sensors=True)
            office.wait(60)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and not any(p.seq >= FRAMES - 1 for p in pf.snapshot()):
                time.sleep(0.1)
            for inbox in (attitude, vo, pf):
                inbox.sub.undeclare()
            watch.close()
        codes = cluster.stop()
    assert all(code == 0 for code in codes.values()), codes
    # yaw: every frame, equal to the in-process tracker (as in the open profile)
    assert sorted(watch.yaw) == list(range(FRAMES))
    assert hostile.max_yaw_error_deg(watch, reference) < 1e-6
    # estimator: its outputs arrive through the policy
    assert len(attitude.snapshot()) >= FRAMES // 2 and len(vo.snapshot()) >= FRAMES // 4
    assert all(np.all(np.isfinite(a.q_world_body)) for a in attitude.snapshot())
    # localizer: converges onto the truth like the open test (10 cm)
    truth = default_flight(n_frames=FRAMES).states
    late = [p for p in pf.snapshot() if p.seq >= FRAMES - 20]
    assert late, "no pose/pf for the last 20 frames"
    assert max(float(np.linalg.norm(p.p_world_body_m - truth[p.seq, :3])) for p in late) < 0.10
    assert attitude.malformed == vo.malformed == pf.malformed == 0
