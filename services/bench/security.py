"""Hostile participants against the open and the secure profile, and the cost of TLS + access control.

For each profile (``open``: plain TCP, no access control; ``secure``: mutual TLS with per-role
certificates and the access-control policy on the router and every peer) a local master-foreman-worker
cluster (2 hosts x 1 worker) runs and every attack of :mod:`services.bench.hostile` is tried against it:
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
from services.bench import hostile
from services.bench.cluster_workload import write_frame_folder
from services.camera import CameraSettings, simulated_flight
from services.demo_cluster import run_cluster_flight
from services.master.service import Topology
from services.secure import SecureProfile
from services.up import ClusterSpec, HostSpec, LocalCluster

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
    parser.add_argument("--secure-dir", type=Path, default=Path("out/secure"), help="certificates, config")


def small_cluster() -> ClusterSpec:
    hosts = (HostSpec(name="h1", workers=1), HostSpec(name="h2", workers=1))
    return ClusterSpec(
        name="security", topology=Topology.MASTER_FOREMAN_WORKER, balance=Balance.TIME, hosts=hosts
    )


ATTACKS = ("forged_outputs", "fake_worker_crops", "liveliness_flood", "forged_frame_flood", "fake_foreman")


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
                result = hostile.attack_forged_outputs(cluster, profile, spec.uav)
            elif name == "fake_worker_crops":
                result = hostile.attack_fake_worker(cluster, profile, frames=40, fps=fps)
            elif name == "liveliness_flood":
                result = hostile.attack_liveliness_flood(cluster, profile, flood_frames, fps)
            elif name == "forged_frame_flood":
                result = hostile.attack_frame_flood(cluster, profile, flood_frames, fps)
            elif name == "fake_foreman":
                frames = max(2, int(foreman_seconds * fps))
                reference = hostile.reference_yaw_rad(frames)
                result = hostile.attack_fake_foreman(cluster, profile, frames, fps, reference)
            else:
                raise ValueError(f"unknown attack {name!r}; known: {', '.join(ATTACKS)}")
            result.evidence["attack_seconds"] = round(time.monotonic() - t0, 1)
            logger.info("%s/%s: succeeded=%s %s", profile, result.name, result.succeeded, result.evidence)
            results.append(result)
    return results


def overhead(
    out_dir: Path, secure_dir: Path, frames: int, repeats: int
) -> dict[str, dict[str, float | list[float]]]:
    """Master ms per frame at 752x480 (master-foreman-worker 1x1), open and secure alternately."""
    flight = simulated_flight(CameraSettings(frames=frames))
    frame_dir = out_dir / "security_frames_752"
    write_frame_folder(frame_dir, [flight.frame(i) for i in range(frames)])
    spec = ClusterSpec(
        name="overhead", topology=Topology.MASTER_FOREMAN_WORKER, hosts=(HostSpec(name="h1", workers=1),)
    )
    secure = SecureProfile.ensure(secure_dir)
    samples: dict[str, list[np.ndarray]] = {p: [] for p in PROFILES}
    lost: dict[str, int] = dict.fromkeys(PROFILES, 0)
    yaw: dict[str, list[np.ndarray]] = {p: [] for p in PROFILES}
    for repeat in range(repeats):
        for profile in PROFILES:
            estimates, _wall, _codes = run_cluster_flight(
                spec, frames, out_dir / "security_logs" / f"overhead-{profile}-{repeat}", fps=0.0,
                in_flight=1, camera_args=("--images", str(frame_dir), "--preload", "--no-sensors"),
                progress=False, secure=secure if profile == "secure" else None,
            )  # fmt: skip
            ms = np.array(
                [estimates[s].timings_ms["total"] for s in sorted(estimates) if s > OVERHEAD_WARMUP]
            )
            samples[profile].append(ms)
            lost[profile] += frames - len(estimates)
            yaw[profile].append(np.array([estimates[s].yaw_rad for s in sorted(estimates)]))
            print(
                f"752x480 [{repeat + 1}/{repeats}] {profile}: median {np.median(ms):.2f} ms/frame", flush=True
            )
    out: dict[str, dict[str, float | list[float]]] = {}
    for profile in PROFILES:
        every = np.concatenate(samples[profile]) if samples[profile] else np.zeros(0)
        out[profile] = {
            "median_ms": float(np.median(every)) if every.size else float("nan"),
            "p95_ms": float(np.percentile(every, 95)) if every.size else float("nan"),
            "run_medians_ms": [float(np.median(m)) for m in samples[profile]],
            "frames_measured": int(every.size),
            "frames_lost": lost[profile],
        }
    same = [
        np.max(np.abs(a - b)) for a, b in zip(yaw["open"], yaw["secure"], strict=True) if a.size == b.size
    ]
    pairs = [
        float(np.median(b) - np.median(a)) for a, b in zip(samples["open"], samples["secure"], strict=True)
    ]
    out["comparison"] = {
        "secure_minus_open_median_ms": out["secure"]["median_ms"] - out["open"]["median_ms"],  # type: ignore[operator]
        #: each repeat runs open then secure back to back: the median of their differences is the least noisy
        "secure_minus_open_paired_ms": pairs,
        "secure_minus_open_paired_median_ms": float(np.median(pairs)) if pairs else float("nan"),
        "max_yaw_difference_rad": float(max(same)) if same else float("nan"),
    }
    return out


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
    if "comparison" in cost:
        paired = cost["comparison"]["secure_minus_open_paired_median_ms"]
        table.append({"attack": "752x480 secure - open", "profile": "paired", "succeeded": "",
                      "evidence": f"median of per-repeat differences {paired:+.2f} ms"})  # fmt: skip
    return {
        "attacks": [r.to_json() for r in results],
        "overhead_752x480": cost,
        "host": "shared with other jobs (2 cores); see run medians for spread",
        "table": table,
    }
