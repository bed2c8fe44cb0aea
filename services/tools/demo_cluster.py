"""The embedded default through a local cluster: router, camera, master, 2 foremen x 2 workers (127.0.0.1).

``run_demo(out_dir)`` starts the processes, replays the simulated hover flight through them (two frames in
flight: the camera renders the next frame while the cluster works on the current one; the master's
frame queue holds the waiting one, so none is dropped) while the in-process core tracks the same frames,
prints live progress, then reports with the yaw demo's ``report_yaw`` (``out/cluster/yaw_cluster.{png,json}``)
plus per-member shares, speeds and frame timings (``cluster_yaw_shares.png``, ``cluster_timings.png``,
``summary.json``). Member shares and timings come from the published YawEstimates themselves.
"""

from __future__ import annotations

import logging
import math
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.datasets.tum import Trajectory
from common.dispatch import Balance
from common.geometry import wrap_angle_rad
from common.members import Topology
from common.sim.flight import HOVER_FRAMES, hover_flight
from common.yaw import YawSettings
from services.runtime.progress import bar as progress_bar
from services.runtime.progress import quiet
from services.runtime.trajectory import write_with_truth
from services.runtime.transport import open_session
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.demo_yaw import report_yaw, track_frames
from services.tools.observe import YawCollector
from services.tools.report import write_json
from services.tools.secure import SecureProfile
from services.tools.up import LocalCluster

logger = logging.getLogger(__name__)
#: seconds between progress lines when no bar is drawn (not a terminal, or CI)
PRINT_PERIOD_S = 10.0

#: frames the demo's camera may have without a yaw: 2 pipelines rendering with the cluster's work (about 1.2x
#: the frame rate of 1 here) and still drops none, since the master queues one frame while it works on another
DEMO_IN_FLIGHT = 2

DEMO_CLUSTER = ClusterSpec(
    name="local2x2",
    topology=Topology.MASTER_FOREMAN_WORKER,
    balance=Balance.TIME,
    hosts=(HostSpec(name="h1", workers=2), HostSpec(name="h2", workers=2)),
)


def run_cluster_flight(
    spec: ClusterSpec,
    n_frames: int,
    log_dir: Path,
    fps: float = 0.0,
    in_flight: int = 1,
    master_args: tuple[str, ...] = (),
    camera_args: tuple[str, ...] = (),
    progress: bool = True,
    shared_memory: bool = False,
    secure: SecureProfile | None = None,
) -> tuple[dict[int, Any], float, dict[str, int | None]]:
    """Run one flight through a fresh local cluster; returns (estimates by seq, wall seconds, exit codes)."""
    with LocalCluster(
        spec, log_dir, shared_memory=shared_memory, master_args=master_args, secure=secure
    ) as cluster:
        t_start = time.monotonic()
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        logger.info(
            "cluster %s up in %.1f s (router %s)", spec.name, time.monotonic() - t_start, cluster.router
        )
        with open_session(cluster.observer_transport()) as session:
            collector = YawCollector(session, spec.uav)
            camera = [
                "--frames", str(n_frames), "--fps", str(fps), "--in-flight", str(in_flight), *camera_args,
            ]  # fmt: skip
            cluster.start_camera(camera)
            t0 = time.monotonic()
            last_print = t0
            timeout_s = 60.0 + n_frames * 0.5
            with progress_bar(total=n_frames, desc=f"yaw cluster {spec.name}", unit="frame") as bar:
                while len(collector.estimates) < n_frames and time.monotonic() - t0 < timeout_s:
                    time.sleep(0.1)
                    camera_process = cluster.processes["camera/camera/0"]
                    if camera_process.poll() is not None and not collector.wait_for(n_frames, 2.0):
                        break
                    bar.set(len(collector.estimates))
                    bar.note(_progress_text(collector))
                    if progress and not bar.shown and time.monotonic() - last_print > PRINT_PERIOD_S:
                        last_print = time.monotonic()
                        print(
                            f"  {len(collector.estimates)}/{n_frames} frames, {_progress_text(collector)}",
                            flush=True,
                        )
            wall_s = time.monotonic() - t0
            estimates = dict(collector.estimates)
            collector.close()
        try:  # the camera ends by itself after its last frame; let it, rather than signal it mid-exit
            cluster.processes["camera/camera/0"].wait(5.0)
        except subprocess.TimeoutExpired:
            logger.warning("camera still running after its flight; stopping it")
        codes = cluster.stop()
    return estimates, wall_s, codes


def _progress_text(collector: YawCollector) -> str:
    newest = collector.newest()
    if newest < 0:
        return "waiting for the first yaw"
    estimate = collector.estimates[newest]
    shares = "/".join(str(n) for m, n in sorted(estimate.members.items()) if ">" not in m)
    return (
        f"yaw {np.degrees(estimate.yaw_rad):+7.2f} deg, {estimate.timings_ms.get('total', 0):.0f} ms, "
        f"shares {shares}"
    )


def member_table(estimates: dict[int, Any]) -> list[dict[str, Any]]:
    """Per member: mean patches per frame, share of all patches, frames served, last speed (patches/s)."""
    seqs = sorted(s for s, e in estimates.items() if e.patch_count)
    totals: dict[str, list[int]] = {}
    for s in seqs:
        for member, count in estimates[s].members.items():
            totals.setdefault(member, []).append(count)
    all_patches = sum(estimates[s].patch_count for s in seqs) or 1
    rows = []
    for member in sorted(totals):
        counts = totals[member]
        speed = next(
            (estimates[s].speeds_patches_s[member] for s in reversed(seqs)
             if member in estimates[s].speeds_patches_s),
            None,
        )  # fmt: skip
        rows.append(
            {
                "member": member,
                "frames": len(counts),
                "patches_per_frame": float(np.mean(counts)),
                "share": float(np.sum(counts)) / all_patches if ">" not in member else float("nan"),
                "speed_patches_s": speed if speed is not None else float("nan"),
            }
        )
    return rows


def _plot(out_dir: Path, flight: Any, estimates: dict[int, Any], rows: list[dict[str, Any]]) -> list[Path]:
    """``cluster_yaw_shares.png`` (yaw on the same reference as ``yaw_cluster.png``: the flight's absolute
    yaw over flight time) and ``cluster_timings.png`` (master time per frame, median and p99 marked)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seqs = np.array(sorted(estimates))
    t_s = flight.frame_stamps_s[seqs]
    truth_deg = np.degrees(flight.yaw_rad[seqs])
    # the cluster integrates yaw from 0 at frame 0: put it on the truth's reference, as report_yaw does
    yaw_deg = np.degrees(np.array([estimates[s].yaw_rad for s in seqs]) + flight.yaw_rad[0])
    error_deg = np.degrees(wrap_angle_rad(np.radians(yaw_deg - truth_deg)))
    total_ms = np.array([estimates[s].timings_ms.get("total", np.nan) for s in seqs])
    paths = []
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    axes[0].plot(t_s, truth_deg, color="black", lw=1.5, label="truth")
    axes[0].plot(t_s, yaw_deg, color="tab:red", lw=1.0, ls="--", label="cluster")
    axes[0].set_ylabel("yaw [deg]")
    axes[0].set_title(f"yaw through the local cluster: {len(seqs)} frames, 2 foremen x 2 workers")
    axes[0].legend(loc="best")
    axes[1].plot(t_s, error_deg, color="tab:blue", lw=0.8)
    axes[1].set_ylabel("yaw error [deg]")
    axes[1].set_title(f"error (cluster - truth): max |e| {np.max(np.abs(error_deg)):.3f} deg")
    top = [r["member"] for r in rows if ">" not in r["member"]]
    stack = np.array([[estimates[s].members.get(m, 0) for s in seqs] for m in top])
    axes[2].stackplot(t_s, stack, labels=top)
    axes[2].set_ylabel("patches per frame")
    axes[2].set_xlabel("flight time [s]")
    axes[2].set_title("share of each foreman (time balancing)")
    axes[2].legend(loc="upper right", fontsize=7)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    paths.append(out_dir / "cluster_yaw_shares.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    finite = total_ms[1:][np.isfinite(total_ms[1:])]  # frame 0 only primes the members' spectra
    fig, ax = plt.subplots(figsize=(8, 4.5))
    if finite.size:
        median, p99 = np.median(finite), np.percentile(finite, 99)
        ax.hist(finite, bins=60, color="tab:gray")
        ax.axvline(median, color="tab:blue", lw=1.5, label=f"median {median:.1f} ms")
        ax.axvline(p99, color="tab:red", lw=1.5, ls="--", label=f"p99 {p99:.1f} ms")
        ax.legend(loc="upper right")
    ax.set_xlabel("master time per frame, taken from its queue to yaw fitted [ms]")
    ax.set_ylabel("frames")
    ax.set_title(f"yaw cluster timing per frame ({finite.size} frames, 752x480, 2 foremen x 2 workers)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    paths.append(out_dir / "cluster_timings.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def member_line(row: dict[str, Any]) -> str:
    """One member's line of the summary; a member that never reported a speed (it computed nothing itself)
    shows none, not "nan patches/s"."""
    name, speed = row["member"], row["speed_patches_s"]
    share = f"share {row['share']:.2f}, " if ">" not in name else ""
    rate = f"{speed:.0f} patches/s" if speed is not None and math.isfinite(speed) else "no speed measured"
    return f"  {name:>34}: {share}{row['patches_per_frame']:.1f} patches/frame, {rate}"


def run_demo(out_dir: Path, n_frames: int = HOVER_FRAMES) -> dict[str, Any]:
    """The hover flight through the local cluster; the in-process core runs alongside for comparison."""
    out = Path(out_dir)
    cluster_dir = out / "cluster"
    cluster_dir.mkdir(parents=True, exist_ok=True)
    flight = hover_flight(seed=0, n_frames=n_frames)
    print(f"cluster demo: router, camera, master, 2 foremen x 2 workers on 127.0.0.1; {n_frames} frames")
    reference: dict[str, Any] = {}
    in_process = threading.Thread(
        target=lambda: reference.update(run=track_frames(flight.frames(), YawSettings(), flight)), daemon=True
    )
    in_process.start()
    estimates, wall_s, codes = run_cluster_flight(
        DEMO_CLUSTER, n_frames, cluster_dir / "logs", in_flight=DEMO_IN_FLIGHT, progress=not quiet()
    )
    in_process.join()
    seqs = np.array(sorted(estimates))
    yaw = np.array([estimates[s].yaw_rad for s in seqs])
    total_ms = np.array([estimates[s].timings_ms.get("total", np.nan) for s in seqs])
    rows = member_table(estimates)
    max_diff_deg = (
        float(np.max(np.degrees(np.abs(yaw - reference["run"].yaw_rad[seqs])))) if seqs.size else None
    )
    extra: dict[str, Any] = {
        "frames_with_yaw": len(estimates),
        "frames_lost": n_frames - len(estimates),
        "dropped_frames": max((e.dropped_frames for e in estimates.values()), default=0),
        "redispatched": sum(e.redispatched for e in estimates.values()),
        "fps": len(estimates) / wall_s if wall_s > 0 else float("nan"),
        "p99_frame_ms": float(np.nanpercentile(total_ms[1:], 99)) if total_ms.size > 1 else float("nan"),
        "max_abs_diff_vs_in_process_deg": max_diff_deg,
        "in_process_ms_per_frame_median": float(np.median(reference["run"].ms_per_frame)),
        "exit_codes": codes,
    }
    summary = report_yaw(
        cluster_dir,
        flight.frame_stamps_s[seqs],
        yaw,
        flight.yaw_rad[seqs],
        ms_per_frame=total_ms[1:] if total_ms.size > 1 else None,
        label="yaw through the local cluster (2 foremen x 2 workers)",
        extra=extra,
        stem="yaw_cluster",
    )
    plots = _plot(cluster_dir, flight, estimates, rows)
    stamps = flight.frame_stamps_s[seqs]
    summary["tum"] = write_with_truth(
        out / "tum", "yaw", Trajectory.from_yaw(stamps, yaw),
        Trajectory.from_yaw(stamps, flight.yaw_rad[seqs] - flight.yaw_rad[0]),
    )  # fmt: skip
    summary["members"] = rows
    summary["plots"] = [str(p) for p in plots]
    write_json(cluster_dir / "summary.json", summary)
    print(
        f"cluster: {len(estimates)}/{n_frames} frames with yaw, {extra['fps']:.1f} fps, "
        f"max |cluster - in-process| {max_diff_deg:.2e} deg, {extra['redispatched']} shares re-dispatched"
    )
    for row in rows:
        print(member_line(row))
    print(f"plots: {', '.join(str(p) for p in plots)}")
    return summary
