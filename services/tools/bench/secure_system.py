"""The whole system, open and secure profile, same run: do they give the same results?

One flight per profile through a fresh local cluster (2 hosts x 1 worker, master-foreman-worker) with the
estimator of uav0 (``--external-yaw``) and the localizer of uav1 (the office flight, simulated odometry):
the yaw of every frame (flow-controlled camera with IMU and rangefinder), uav0's ``attitude`` and
``pose/vo`` and uav1's ``pose/pf``. In the secure profile every participant holds only its own role's
certificate and our observer is a read-only ``client``.

:func:`compare` puts them side by side: the yaw per frame (both equal to the in-process tracker), the
estimator's roll/pitch error against the simulator's truth and the localizer's position error at the end,
each profile against the same bounds, and how far the two profiles' outputs are from each other.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from common.geometry import euler_from_quaternion, wrap_angle_rad
from common.sim.scene import default_flight
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import AttitudeEstimate, PoseEstimate
from common.wire.schema import WireError
from services.camera import CameraSettings, simulated_flight
from services.runtime.transport import open_session, zbytes
from services.tools.bench import hostile
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.secure import SecureProfile
from services.tools.up import LocalCluster

#: the bounds both profiles must meet (the open profile's own tests use the same)
YAW_BOUND_DEG = 1e-6
ROLL_PITCH_BOUND_DEG = 2.0
PF_BOUND_M = 0.10
#: frames at the end over which the localizer's error is judged
PF_LATE_FRAMES = 20


class Inbox:
    """Every decoded message of one key (malformed ones counted)."""

    def __init__(self, session: zenoh.Session, key: str, expected: type[Any]) -> None:
        self.messages: list[Any] = []
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

    def snapshot(self) -> list[Any]:
        with self._lock:
            return list(self.messages)


@dataclass
class SystemRun:
    profile: str
    frames: int
    yaw: dict[int, float]
    attitude: list[AttitudeEstimate]
    vo: list[PoseEstimate]
    pf: list[PoseEstimate]
    malformed: int
    exit_codes: dict[str, int | None] = field(default_factory=dict)
    seconds: float = 0.0


def system_cluster() -> ClusterSpec:
    hosts = (HostSpec(name="h1", workers=1), HostSpec(name="h2", workers=1))
    return ClusterSpec(name="system", hosts=hosts)


def run_system(profile: str, root: Path, frames: int = 80, fps: float = 10.0) -> SystemRun:
    """One flight of the whole system under ``profile`` (``open`` or ``secure``; certificates in
    ``root/secure``, logs in ``root/logs-{profile}``)."""
    secure = SecureProfile.ensure(root / "secure") if profile == "secure" else None
    t0 = time.monotonic()
    with LocalCluster(system_cluster(), root / f"logs-{profile}", secure=secure) as cluster:
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
            time.sleep(0.5)  # the subscriptions reach the publishers
            office = cluster.spawn(
                "camera/office/0",
                [
                    "camera", *transport, "--node", "office", "--uav", "uav1", "--flight", "office",
                    "--frames", str(frames), "--fps", str(fps / 2), "--wait-master", "0",
                ],
                common_name="camera.uav1",
            )  # fmt: skip
            hostile.fly(cluster, watch, frames, fps=fps, timeout_s=120.0, in_flight=1, sensors=True)
            office.wait(60)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and not any(p.seq >= frames - 1 for p in pf.snapshot()):
                time.sleep(0.1)
            for inbox in (attitude, vo, pf):
                inbox.sub.undeclare()
            watch.close()
        codes = cluster.stop()
    return SystemRun(
        profile, frames, dict(watch.yaw), attitude.snapshot(), vo.snapshot(), pf.snapshot(),
        attitude.malformed + vo.malformed + pf.malformed, codes, time.monotonic() - t0,
    )  # fmt: skip


def roll_pitch_error_deg(run: SystemRun) -> np.ndarray:
    """Roll and pitch error of uav0's attitude against the simulator's truth at each estimate's stamp."""
    if not run.attitude:
        return np.zeros((0, 2))
    imu = simulated_flight(CameraSettings(frames=run.frames)).imu
    stamps = np.array([a.stamp_s for a in run.attitude])
    idx = np.clip(np.searchsorted(imu.stamps_s, stamps - 1e-9), 0, imu.stamps_s.size - 1)
    q = np.array([a.q_world_body for a in run.attitude])
    err = euler_from_quaternion(q) - euler_from_quaternion(imu.true_q_world_body[idx])
    return np.asarray(np.degrees(wrap_angle_rad(err))[:, :2], dtype=np.float64)


def summarise(run: SystemRun, reference_rad: np.ndarray) -> dict[str, Any]:
    """One profile's results and whether each meets its bound."""
    truth = default_flight(n_frames=run.frames).states
    late = [p for p in run.pf if p.seq >= run.frames - PF_LATE_FRAMES]
    pf_error = max((float(np.linalg.norm(p.p_world_body_m - truth[p.seq, :3])) for p in late), default=np.nan)
    roll_pitch = roll_pitch_error_deg(run)
    rp_max = float(np.max(np.abs(roll_pitch))) if roll_pitch.size else float("nan")
    yaw_error = hostile.max_yaw_error_deg_of(run.yaw, reference_rad)
    out: dict[str, Any] = {
        "yaw_frames": len(run.yaw),
        "yaw_max_error_deg": yaw_error,
        "attitude_messages": len(run.attitude),
        "roll_pitch_max_error_deg": rp_max,
        "pose_vo_messages": len(run.vo),
        "pose_pf_messages": len(run.pf),
        "pf_late_max_error_m": pf_error,
        "malformed": run.malformed,
        "all_exited_0": all(code == 0 for code in run.exit_codes.values()),
        "seconds": round(run.seconds, 1),
    }
    checks = [  # (what, holds, measured against its bound): a failed run says which bound and by how much
        (
            "every frame has a yaw",
            sorted(run.yaw) == list(range(run.frames)),
            f"{len(run.yaw)} of {run.frames}",
        ),
        ("yaw error", yaw_error < YAW_BOUND_DEG, f"{yaw_error:.4f} deg, bound {YAW_BOUND_DEG}"),
        (
            "attitudes",
            len(run.attitude) >= run.frames // 2,
            f"{len(run.attitude)}, at least {run.frames // 2}",
        ),
        (
            "roll/pitch error",
            rp_max < ROLL_PITCH_BOUND_DEG,
            f"{rp_max:.3f} deg, bound {ROLL_PITCH_BOUND_DEG}",
        ),
        ("pose/vo messages", len(run.vo) >= run.frames // 4, f"{len(run.vo)}, at least {run.frames // 4}"),
        ("late pose/pf error", pf_error < PF_BOUND_M, f"{pf_error:.3f} m, bound {PF_BOUND_M}"),
        ("malformed", run.malformed == 0, f"{run.malformed}"),
        ("exit codes", out["all_exited_0"], f"{run.exit_codes}"),
    ]
    out["failed_bounds"] = [f"{what}: {measured}" for what, holds, measured in checks if not holds]
    out["meets_bounds"] = not out["failed_bounds"]
    return out


def compare(runs: dict[str, SystemRun]) -> dict[str, Any]:
    """Both profiles against the same bounds, and their outputs against each other."""
    reference = hostile.reference_yaw_rad(max(r.frames for r in runs.values()))
    out: dict[str, Any] = {name: summarise(run, reference) for name, run in runs.items()}
    if {"open", "secure"} <= set(runs):
        a, b = runs["open"], runs["secure"]
        common = sorted(set(a.yaw) & set(b.yaw))
        vo_a, vo_b = {p.seq: p for p in a.vo}, {p.seq: p for p in b.vo}
        pf_a, pf_b = {p.seq: p for p in a.pf}, {p.seq: p for p in b.pf}
        out["secure_vs_open"] = {
            "yaw_frames_compared": len(common),
            "yaw_max_difference_rad": max((abs(a.yaw[s] - b.yaw[s]) for s in common), default=float("nan")),
            "pose_vo_max_difference_m": _max_position_difference(vo_a, vo_b),
            "pose_pf_max_difference_m": _max_position_difference(pf_a, pf_b),
            "same_results": bool(out["open"]["meets_bounds"] and out["secure"]["meets_bounds"]),
        }
    return out


def _max_position_difference(a: dict[int, PoseEstimate], b: dict[int, PoseEstimate]) -> float:
    common = sorted(set(a) & set(b))
    return max(
        (float(np.linalg.norm(a[s].p_world_body_m - b[s].p_world_body_m)) for s in common),
        default=float("nan"),
    )
