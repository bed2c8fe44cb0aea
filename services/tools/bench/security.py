"""Hostile participants against the open and the secure profile, and the cost of TLS + access control.

For each profile (``open``: plain TCP, no access control; ``secure``: mutual TLS with per-role
certificates and the access-control policy on the router and every peer) a local master-foreman-worker
cluster (2 hosts x 1 worker) runs and every attack of :mod:`services.tools.bench.hostile` is tried against it:
forged outputs, a fake worker, a liveliness flood, a forged-frame flood and a fake foreman answering
wrong shifts. Each gives ``name``, ``profile``, ``succeeded`` and its evidence.

The cost: the 752x480 master-foreman-worker 1x1 path (pre-rendered frames replayed in lock-step, shared
memory off), open and secure alternately in the same run; median and p95 of the master's ms per frame.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.dispatch import Balance
from common.members import Role, Topology
from services.camera import CameraSettings, simulated_flight
from services.tools.bench import election, forgery, hostile, secure_system, takeover
from services.tools.bench.cluster_workload import write_frame_folder
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.demo_cluster import run_cluster_flight
from services.tools.secure import SecureProfile
from services.tools.up import LocalCluster

NAME = "security"
logger = logging.getLogger(__name__)
PROFILES = ("open", "secure")
OVERHEAD_WARMUP = 10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profiles", default="open,secure", help="comma-separated: open, secure")
    parser.add_argument("--attacks", default="all", help="comma-separated attack names, or all")
    parser.add_argument("--foreman-seconds", type=float, default=20.0, help="fake-foreman run length (s)")
    parser.add_argument("--fps", type=float, default=10.0, help="camera rate of the attack runs")
    parser.add_argument("--flood-frames", type=int, default=100, help="real frames under each flood")
    parser.add_argument("--overhead-frames", type=int, default=80, help="frames per 752x480 overhead run")
    parser.add_argument("--overhead-repeats", type=int, default=3, help="open/secure pairs of overhead runs")
    parser.add_argument(
        "--system-frames", type=int, default=80, help="frames of the whole-system run per profile (0: skip)"
    )
    parser.add_argument("--secure-dir", type=Path, default=Path("out/secure"), help="certificates, config")


def small_cluster() -> ClusterSpec:
    hosts = (HostSpec(name="h1", workers=1), HostSpec(name="h2", workers=1))
    return ClusterSpec(
        name="security", topology=Topology.MASTER_FOREMAN_WORKER, balance=Balance.TIME, hosts=hosts
    )


#: in this order: the last two kill the active master (a standby takes over; the killed one comes back as a
#: standby after the candidate token attack)
ATTACKS = (
    "forged_outputs", "fake_worker_crops", "other_node_member", "liveliness_flood", "forged_frame_flood",
    "fake_foreman", "forged_leader_token", "forged_candidate_token", "forged_yaw_takeover",
)  # fmt: skip


def run_attacks(
    profile: str,
    log_dir: Path,
    secure_dir: Path,
    attacks: tuple[str, ...] = ATTACKS,
    fps: float = 10.0,
    foreman_seconds: float = 20.0,
    flood_frames: int = 100,
) -> list[hostile.AttackResult]:
    """Every attack in ``attacks`` against one fresh cluster of ``profile``."""
    secure = SecureProfile.ensure(secure_dir) if profile == "secure" else None
    spec = small_cluster()
    results: list[hostile.AttackResult] = []
    with LocalCluster(spec, log_dir / profile, secure=secure) as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        for name in attacks:
            t0 = time.monotonic()
            if name == "forged_outputs":
                result = forgery.attack_forged_outputs(cluster, profile, spec.uav)
            elif name == "fake_worker_crops":
                result = hostile.attack_fake_worker(cluster, profile, frames=40, fps=fps)
            elif name == "other_node_member":  # another node's stolen certificates, on h1
                worker = hostile.attack_fake_worker(cluster, profile, 40, fps, "worker.h2")
                result = hostile.attack_fake_worker(cluster, profile, 40, fps, "foreman.h2", Role.FOREMAN)
                result.evidence["worker"] = worker.evidence
                result.succeeded = result.succeeded or worker.succeeded
            elif name == "liveliness_flood":
                result = hostile.attack_liveliness_flood(cluster, profile, flood_frames, fps)
            elif name == "forged_frame_flood":
                result = hostile.attack_frame_flood(cluster, profile, flood_frames, fps)
            elif name == "fake_foreman":
                frames = max(2, int(foreman_seconds * fps))
                reference = hostile.reference_yaw_rad(frames)
                result = hostile.attack_fake_foreman(cluster, profile, frames, fps, reference)
            elif name == "forged_leader_token":
                result = election.attack_forged_leader(cluster, profile, 40, fps)
            elif name == "forged_candidate_token":
                result = election.attack_forged_candidate(cluster, profile, 40, fps)
            elif name == "forged_yaw_takeover":
                reference = hostile.reference_yaw_rad(flood_frames)
                result = takeover.attack_forged_yaw_takeover(cluster, profile, flood_frames, fps, reference)
            else:
                raise ValueError(f"unknown attack {name!r}; known: {', '.join(ATTACKS)}")
            result.evidence["attack_seconds"] = round(time.monotonic() - t0, 1)
            logger.info("%s/%s: succeeded=%s %s", profile, result.name, result.succeeded, result.evidence)
            results.append(result)
    return results


def overhead(out_dir: Path, secure_dir: Path, frames: int, repeats: int) -> dict[str, dict[str, Any]]:
    """Master ms per frame at 752x480 (master-foreman-worker 1x1), open and secure alternately."""
    flight = simulated_flight(CameraSettings(frames=frames))
    frame_dir = out_dir / "security_frames_752"
    write_frame_folder(frame_dir, [flight.frame(i) for i in range(frames)])
    spec = ClusterSpec(
        name="overhead", topology=Topology.MASTER_FOREMAN_WORKER, hosts=(HostSpec(name="h1", workers=1),)
    )
    secure = SecureProfile.ensure(secure_dir)
    runs: dict[str, list[dict[int, tuple[float, float]]]] = {p: [] for p in PROFILES}
    lost: dict[str, int] = dict.fromkeys(PROFILES, 0)
    for repeat in range(repeats):
        # alternate which profile goes first, so that a drift of the host's load does not favour one
        for profile in PROFILES if repeat % 2 == 0 else PROFILES[::-1]:
            estimates, _wall, _codes = run_cluster_flight(
                spec, frames, out_dir / "security_logs" / f"overhead-{profile}-{repeat}", fps=0.0,
                in_flight=1, camera_args=("--images", str(frame_dir), "--preload", "--no-sensors"),
                progress=False, secure=secure if profile == "secure" else None,
            )  # fmt: skip
            runs[profile].append({s: (e.timings_ms["total"], e.yaw_rad) for s, e in estimates.items()})
            lost[profile] += frames - len(estimates)
            ms = [t for s, (t, _) in runs[profile][-1].items() if s > OVERHEAD_WARMUP]
            print(
                f"752x480 [{repeat + 1}/{repeats}] {profile}: median {np.median(ms):.2f} ms/frame", flush=True
            )
    out: dict[str, dict[str, Any]] = {}
    for profile in PROFILES:
        every = np.array([t for run in runs[profile] for s, (t, _) in run.items() if s > OVERHEAD_WARMUP])
        out[profile] = {
            "median_ms": float(np.median(every)) if every.size else float("nan"),
            "p95_ms": float(np.percentile(every, 95)) if every.size else float("nan"),
            "run_medians_ms": [
                float(np.median([t for s, (t, _) in run.items() if s > OVERHEAD_WARMUP]))
                for run in runs[profile]
            ],
            "frames_measured": int(every.size),
            "frames_lost": lost[profile],
        }
    out["comparison"] = paired_differences(runs["open"], runs["secure"])
    return out


def _stats(values: list[float]) -> dict[str, Any]:
    v = np.asarray(values, dtype=np.float64)
    if not v.size:
        return {"n": 0}
    return {
        "n": int(v.size),
        "median_ms": float(np.median(v)),
        "p95_ms": float(np.percentile(v, 95)),
        "min_ms": float(v.min()),
        "max_ms": float(v.max()),
    }


def paired_differences(
    open_runs: list[dict[int, tuple[float, float]]], secure_runs: list[dict[int, tuple[float, float]]]
) -> dict[str, Any]:
    """Secure minus open, paired within each repeat (the two runs of a repeat replay the same frames back
    to back): per repeat the difference of the run medians, and per frame the difference of the same
    frame's ms; their median and p95. Also the largest yaw difference of a frame between the profiles."""
    per_repeat: list[float] = []
    per_frame: list[float] = []
    yaw_difference = 0.0
    for a, b in zip(open_runs, secure_runs, strict=True):
        both = sorted(s for s in set(a) & set(b) if s > OVERHEAD_WARMUP)
        if not both:
            continue
        per_repeat.append(float(np.median([b[s][0] for s in both]) - np.median([a[s][0] for s in both])))
        per_frame += [b[s][0] - a[s][0] for s in both]
        yaw_difference = max(yaw_difference, max(abs(b[s][1] - a[s][1]) for s in set(a) & set(b)))
    return {
        "secure_minus_open_per_repeat_ms": [round(d, 3) for d in per_repeat],
        "secure_minus_open_per_repeat": _stats(per_repeat),
        "secure_minus_open_per_frame": _stats(per_frame),
        "max_yaw_difference_rad": yaw_difference,
    }


def system_row(profile: str, row: dict[str, Any]) -> dict[str, Any]:
    evidence = (
        f"meets bounds {row['meets_bounds']}: yaw {row['yaw_frames']} frames (max error "
        f"{row['yaw_max_error_deg']:.1e} deg), roll/pitch error {row['roll_pitch_max_error_deg']:.2f} deg, "
        f"pose/pf late error {row['pf_late_max_error_m']:.3f} m"
    )
    return {"attack": "whole system", "profile": profile, "succeeded": "", "evidence": evidence}


def run(args: argparse.Namespace) -> dict[str, Any]:
    out_dir = Path(args.out)
    profiles = tuple(p.strip() for p in args.profiles.split(",") if p.strip())
    attacks = ATTACKS if args.attacks == "all" else tuple(a.strip() for a in args.attacks.split(","))
    results: list[hostile.AttackResult] = []
    for profile in profiles:
        if profile not in PROFILES:
            raise ValueError(f"unknown profile {profile!r}")
        results += run_attacks(
            profile, out_dir / "security_logs", args.secure_dir, attacks, args.fps, args.foreman_seconds,
            args.flood_frames,
        )  # fmt: skip
    cost = (
        overhead(out_dir, args.secure_dir, args.overhead_frames, args.overhead_repeats)
        if args.overhead_repeats
        else {}
    )
    table = [
        {"attack": r.name, "profile": r.profile, "succeeded": r.succeeded,
         "evidence": ", ".join(f"{k}={v}" for k, v in r.evidence.items() if k != "refused")}
        for r in results
    ]  # fmt: skip
    for profile in PROFILES:
        if profile in cost:
            row = cost[profile]
            table.append({"attack": "752x480 ms/frame", "profile": profile, "succeeded": "",
                          "evidence": f"median {row['median_ms']:.2f}, p95 {row['p95_ms']:.2f}"})  # fmt: skip
    if cost.get("comparison", {}).get("secure_minus_open_per_repeat", {}).get("n"):
        for kind in ("per_repeat", "per_frame"):
            d = cost["comparison"][f"secure_minus_open_{kind}"]
            table.append({"attack": f"752x480 secure - open, paired {kind.replace('_', ' ')}",
                          "profile": f"n={d['n']}", "succeeded": "",
                          "evidence": f"median {d['median_ms']:+.2f} ms, p95 {d['p95_ms']:+.2f} ms, "
                                      f"range [{d['min_ms']:+.2f}, {d['max_ms']:+.2f}]"})  # fmt: skip
    system = secure_system.compare(
        {p: secure_system.run_system(p, out_dir / "security_system", args.system_frames) for p in PROFILES}
    ) if args.system_frames else {}  # fmt: skip
    table += [system_row(profile, system[profile]) for profile in PROFILES if profile in system]
    return {
        "attacks": [r.to_json() for r in results],
        "overhead_752x480": cost,
        "system_open_vs_secure": system,
        "host": "shared with other jobs (2 cores); see run medians for spread",
        "table": table,
    }
