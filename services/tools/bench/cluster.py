"""Paper A's comparison on a heterogeneous local cluster:
in-process vs master-worker vs master-foreman-worker.

Workload: simulated hover frames at 1920x1080 with a 16x12 grid of 128 px patches (192 patches) at pyramid
level 0, pre-rendered once and replayed by the camera (``--images --preload``) in lock-step (one frame in
flight), so every configuration sees the same frames and none is dropped. Heterogeneous cluster: host
``a`` = one worker pinned to core 0, host ``b`` = four workers sharing core 1 (``taskset``). Shared memory
is off by default so the numbers stand for separate hosts. Per frame the master's own time (frame in ->
yaw out) is measured; the in-process baseline is ``YawTracker.track`` on the same frames.

A second, small measurement gives the overhead at 752x480 (40 patches): the median master time per frame of
local paths (master-worker with 1 worker; master-foreman-worker 1x1 and 2x2) minus the in-process median.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from common.dispatch import Balance, SpeedSource
from common.members import Topology
from common.yaw import YawSettings
from services.camera import CameraSettings, simulated_flight
from services.runtime.cli import parse_size
from services.tools.bench.cluster_overhead import OVERHEAD_WARMUP, overhead_752x480, reply_handoff
from services.tools.bench.cluster_workload import in_process_ms, stats_ms, write_frame_folder
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.demo_cluster import run_cluster_flight

NAME = "cluster"
logger = logging.getLogger(__name__)

BIG_GRID = ("16x12", 128, 0)  # grid, patch size, pyramid level -> 192 patches of 128 px at full resolution


def at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum`` (else a usage error naming the bound)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--frames", type=at_least(1), default=100, help="frames per configuration (after warm-up)"
    )
    parser.add_argument(
        "--warmup", type=at_least(0), default=20, help="frames excluded from the statistics (shares converge)"
    )
    parser.add_argument(
        "--repeats", type=at_least(1), default=2, help="runs of every configuration, alternating none/time"
    )
    parser.add_argument(
        "--speed",
        choices=["reported", "round-trip"],
        default="round-trip",
        help="speed measure of time balancing (capataz master/foreman --speed)",
    )
    parser.add_argument("--resolution", default="1920x1080", help="frame size WIDTHxHEIGHT")
    parser.add_argument("--shm", action="store_true", help="zenoh shared memory on (same-host numbers)")
    parser.add_argument(
        "--overhead-frames",
        type=at_least(OVERHEAD_WARMUP + 10),
        default=200,
        help=f"frames of the 752x480 overhead run (the first {OVERHEAD_WARMUP} are not measured)",
    )
    parser.add_argument(
        "--overhead-repeats",
        type=at_least(1),
        default=3,
        help="runs of each 752x480 path (the median is reported)",
    )
    parser.add_argument(
        "--slow-factor",
        type=int,
        default=1,
        help="EMULATION, off by default: host b's workers also repeat each computation this many times "
        "(1 = the issue's cluster, made real by taskset only)",
    )


def _fmt(values: list[float]) -> str:
    return ", ".join(f"{v:.2f}" for v in values)


def heterogeneous(
    topology: str, balance: str, slow_factor: int = 1, speed: str = "round-trip"
) -> ClusterSpec:
    """The issue's cluster: host a = 1 worker pinned to core 0, host b = 4 workers sharing core 1."""
    return ClusterSpec(
        name=f"{topology}-{balance}",
        topology=Topology(topology),
        balance=Balance(balance),
        speed=SpeedSource(speed),
        hosts=(
            HostSpec(name="a", workers=1, cpus="0"),
            HostSpec(name="b", workers=4, cpus="1", cpu_factor=slow_factor),
        ),
        # master, camera and router are not pinned (pinned to a busy core they slow every configuration)
    )


def _yaw_settings(grid: str, patch: int, level: int) -> YawSettings:
    cols, rows = parse_size(grid, "grid", "8x5")
    return YawSettings(grid_cols=cols, grid_rows=rows, patch_size_px=patch, pyramid_level=level)


def shares_and_speeds(estimates: dict[int, Any], last: int = 20) -> dict[str, dict[str, float]]:
    """Mean share of the top-level members over the last frames, and their mean measured speed (patches/s)."""
    seqs = sorted(s for s, e in estimates.items() if e.patch_count)[-last:]
    members = sorted({m for s in seqs for m in estimates[s].members if ">" not in m})
    out: dict[str, dict[str, float]] = {}
    for member in members:
        share = np.mean([estimates[s].members.get(member, 0) / estimates[s].patch_count for s in seqs])
        speeds = [
            estimates[s].speeds_patches_s[member] for s in seqs if member in estimates[s].speeds_patches_s
        ]
        out[member] = {
            "share": float(share),
            "speed_patches_s": float(np.mean(speeds)) if speeds else float("nan"),
        }
    return out


def _rounded(members: dict[str, dict[str, float]]) -> dict[str, float]:
    return {m: round(v["share"], 3) for m, v in members.items()}


def share_speed_error(members: dict[str, dict[str, float]]) -> float:
    """max over members of |share - speed / sum(speeds)| / (speed / sum(speeds))."""
    speeds = np.array([m["speed_patches_s"] for m in members.values()])
    shares = np.array([m["share"] for m in members.values()])
    if not np.all(np.isfinite(speeds)) or speeds.sum() <= 0:
        return float("nan")
    ideal = speeds / speeds.sum()
    return float(np.max(np.abs(shares - ideal) / ideal))


def run(args: argparse.Namespace) -> dict[str, Any]:
    out_dir = Path(args.out)
    width, height = parse_size(args.resolution, "--resolution", "752x480")
    n = args.frames + args.warmup + 1
    frame_dir = out_dir / "cluster_frames"
    flight = simulated_flight(CameraSettings(width=width, height=height, frames=max(n, 2)))
    frames = [flight.frame(i) for i in range(n)]
    write_frame_folder(frame_dir, frames)
    grid, patch, level = BIG_GRID
    settings = _yaw_settings(grid, patch, level)
    seq_ms, seq_yaw = in_process_ms(frames, settings, args.warmup)
    sequential = stats_ms(seq_ms)
    print(f"in-process sequential: median {sequential['median_ms']:.1f} ms/frame", flush=True)
    master_args = (
        "--grid",
        grid,
        "--patch-size",
        str(patch),
        "--pyramid-level",
        str(level),
        "--budget-ms",
        "5000",
    )
    camera_args = ("--images", str(frame_dir), "--preload", "--no-sensors")
    configs: list[dict[str, Any]] = [
        {
            "name": "in-process sequential",
            "topology": "sequential",
            "balance": "-",
            **sequential,
            "fps": 1e3 / sequential["mean_ms"],
            "speedup": 1.0,
            "frames_lost": 0,
            "shares": {},
            "max_yaw_diff_deg": 0.0,
        },
    ]
    frames_lost = 0
    runs: dict[tuple[str, str], list[dict[str, Any]]] = {}
    # repeats alternate none/time so that a change of the (shared) machine's load hits both alike
    for repeat in range(args.repeats):
        for topology in ("master-worker", "master-foreman-worker"):
            for balance in ("none", "time"):
                spec = heterogeneous(topology, balance, args.slow_factor, args.speed)
                estimates, wall_s, _codes = run_cluster_flight(
                    spec,
                    n,
                    out_dir / "cluster_logs" / f"{spec.name}-{repeat}",
                    fps=0.0,
                    in_flight=1,
                    master_args=master_args,
                    camera_args=camera_args,
                    progress=False,
                    shared_memory=args.shm,
                )
                lost = n - len(estimates)
                frames_lost += lost
                # warm-up excluded: shares have converged (EMA) and caches are warm after it
                ms = np.array(
                    [estimates[s].timings_ms["total"] for s in sorted(estimates) if s > args.warmup]
                )
                members = shares_and_speeds(estimates)
                yaw = np.array([estimates[s].yaw_rad if s in estimates else np.nan for s in range(n)])
                run_row = {
                    "ms": ms,
                    "median_ms": float(np.median(ms)) if ms.size else float("nan"),
                    "fps": len(estimates) / wall_s if wall_s > 0 else float("nan"),
                    "lost": lost,
                    "shares": members,
                    "share_speed_error": share_speed_error(members),
                    "max_yaw_diff_deg": float(np.nanmax(np.degrees(np.abs(yaw - seq_yaw)))),
                }
                runs.setdefault((topology, balance), []).append(run_row)
                print(
                    f"[{repeat + 1}/{args.repeats}] {topology} / {balance}: "
                    f"median {run_row['median_ms']:.1f} ms, "
                    f"shares {_rounded(members)}, share error {run_row['share_speed_error']:.3f}",
                    flush=True,
                )
    for (topology, balance), rows in runs.items():
        pooled = np.concatenate([r["ms"] for r in rows])
        stats = (
            stats_ms(pooled)
            if pooled.size
            else {"median_ms": float("nan"), "p99_ms": float("nan"), "mean_ms": float("nan")}
        )
        members = rows[-1]["shares"]
        row = {
            "name": f"{topology} / {balance}",
            "topology": topology,
            "balance": balance,
            **stats,
            "run_medians_ms": [r["median_ms"] for r in rows],
            "fps": float(np.median([r["fps"] for r in rows])),
            "speedup": sequential["median_ms"] / stats["median_ms"],
            "frames_lost": sum(r["lost"] for r in rows),
            "shares": members,
            "share_speed_error": rows[-1]["share_speed_error"],
            "run_share_speed_errors": [r["share_speed_error"] for r in rows],
            "max_yaw_diff_deg": max(r["max_yaw_diff_deg"] for r in rows),
        }
        configs.append(row)
        print(
            f"{row['name']}: median {row['median_ms']:.1f} ms (runs {_fmt(row['run_medians_ms'])}), "
            f"p99 {row['p99_ms']:.1f} ms, speedup {row['speedup']:.2f}, shares {_rounded(members)}",
            flush=True,
        )
    run_gains = {
        topology: [
            none["median_ms"] / time_["median_ms"]
            for none, time_ in zip(runs[(topology, "none")], runs[(topology, "time")], strict=True)
        ]
        for topology in ("master-worker", "master-foreman-worker")
    }

    by = {(c["topology"], c["balance"]): c for c in configs}
    gain_mfw = (
        by[("master-foreman-worker", "none")]["median_ms"]
        / by[("master-foreman-worker", "time")]["median_ms"]
    )
    gain_mw = by[("master-worker", "none")]["median_ms"] / by[("master-worker", "time")]["median_ms"]
    emulation = args.slow_factor != 1
    label = (
        f"EMULATION: host b's workers repeat each computation {args.slow_factor}x in software"
        if emulation
        else "taskset only (no software slow-down)"
    )
    print(
        f"balance gain ({label}): MFW {gain_mfw:.2f}x (runs {_fmt(run_gains['master-foreman-worker'])}), "
        f"MW {gain_mw:.2f}x (runs {_fmt(run_gains['master-worker'])})",
        flush=True,
    )
    overhead = overhead_752x480(out_dir, args.overhead_frames, args.shm, args.overhead_repeats)
    for label, row in overhead["paths"].items():
        if row["frames_computed_by_master"]:
            logger.warning("752x480 %s: the master computed %d frames itself: not a measurement of the path",
                           label, row["frames_computed_by_master"])  # fmt: skip
    handoff = reply_handoff(out_dir, args.shm)
    result = {
        "workload": {
            "resolution": f"{width}x{height}",
            "patches": settings.grid_cols * settings.grid_rows,
            "patch_size_px": patch,
            "pyramid_level": level,
            "frames": args.frames,
            "warmup": args.warmup,
            "shared_memory": bool(args.shm),
            "hosts": "a: 1 worker (+ its foreman) on core 0; b: 4 workers (+ their foreman) sharing core 1",
            "unpinned": "router, camera, master (idle while the workers compute: one frame in flight)",
            "slow_factor": args.slow_factor,
            "slowdown": label,
            "speed_source": args.speed,
            "repeats": args.repeats,
        },
        "configs": configs,
        "frames_lost": frames_lost,
        "balance_gain": gain_mfw,
        "balance_gain_runs": run_gains["master-foreman-worker"],
        "balance_gain_master_worker": gain_mw,
        "balance_gain_master_worker_runs": run_gains["master-worker"],
        "overhead_752x480": overhead,
        "reply_handoff": handoff,
    }
    result["table"] = [
        {
            "config": c["name"],
            "median_ms": c["median_ms"],
            "p99_ms": c["p99_ms"],
            "fps": c["fps"],
            "speedup": c["speedup"],
            "lost": c["frames_lost"],
            "share_err": c.get("share_speed_error", float("nan")),
            "max_dyaw_deg": c["max_yaw_diff_deg"],
        }
        for c in configs
    ]
    tag = "emulated" if emulation else "taskset only"
    # ratios of medians, not times: their own column (they were in median_ms)
    result["table"].append({"config": f"balance gain MFW none/time ({tag})", "ratio": gain_mfw})
    result["table"].append({"config": f"balance gain MW none/time ({tag})", "ratio": gain_mw})
    for label, row in overhead["paths"].items():
        result["table"].append(
            {
                "config": f"752x480 overhead per frame {label} (median of {args.overhead_repeats})",
                "overhead_ms": row["overhead_ms"],
            }
        )
    for mode in ("callback", "channel"):
        result["table"].append(
            {"config": f"752x480 job round trip, reply via {mode}", "round_trip_ms": handoff[f"{mode}_ms"]}
        )
    result["plot"] = str(plot(out_dir / "cluster.png", configs, gain_mfw))
    return result


def _short(name: str) -> str:
    for long, short in (("master-foreman-worker", "MFW"), ("master-worker", "MW"), (" / ", "\nbalance "),
                        ("in-process sequential", "in-process\nsequential")):  # fmt: skip
        name = name.replace(long, short)
    return name


def plot(path: Path, configs: list[dict[str, Any]], gain: float) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_time, ax_share) = plt.subplots(1, 2, figsize=(13, 4.8))
    names = [_short(c["name"]) for c in configs]
    x = np.arange(len(configs))
    ax_time.bar(x - 0.2, [c["median_ms"] for c in configs], 0.4, label="median")
    ax_time.bar(x + 0.2, [c["p99_ms"] for c in configs], 0.4, label="p99")
    for xi, c in zip(x, configs, strict=True):
        ax_time.text(xi, c["p99_ms"], f"x{c['speedup']:.2f}", ha="center", va="bottom", fontsize=8)
    ax_time.set_xticks(x, names, fontsize=7)
    ax_time.set_ylabel("ms per frame")
    ax_time.set_title(f"time per frame (speedup vs sequential); balance gain MFW {gain:.2f}x")
    ax_time.legend()
    cluster = [c for c in configs if c["shares"]]
    bottom = np.zeros(len(cluster))
    members = sorted({m for c in cluster for m in c["shares"]})
    for member in members:
        values = np.array([c["shares"].get(member, {}).get("share", 0.0) for c in cluster])
        ax_share.bar(np.arange(len(cluster)), values, bottom=bottom, label=member)
        bottom += values
    ax_share.set_xticks(np.arange(len(cluster)), [_short(c["name"]) for c in cluster], fontsize=8)
    ax_share.set_ylabel("share of patches")
    ax_share.set_title("shares per member (mean of the last 20 frames)")
    ax_share.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
