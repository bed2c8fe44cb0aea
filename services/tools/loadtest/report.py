"""The load test's outputs: ``out/loadtest/<name>.json``, a terminal table and a figure of the run."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any


def _clean(value: Any) -> Any:
    """JSON without NaN/inf (null instead)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def write_json(report: dict[str, Any], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_clean(report), indent=1))
    return path


def _f(value: Any, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def _pct(share: Any) -> str:
    return "-" if share is None else f"{100 * share:.0f} %"


def _warm(warmup: Any) -> str:
    return "-" if not warmup else f"{warmup['lost']}/{warmup['published']}"


def table(report: dict[str, Any]) -> str:
    """The run as text: one row per stream, one per fault, one per objective.

    Per stream ``cluster`` is the share of patches the foremen and workers computed, ``alone`` the frames
    the master computed entirely itself, ``warm-up lost`` the frames of the warm-up (before the clock,
    not in the statistics) lost of those sent; ``shares`` each member's share of the patches (``self``:
    the master's own), where the balancer put the work."""
    warm = f", warm-up {report['warmup_s']:g} s before the clock" if report.get("warmup_s") else ""
    lines = [
        f"load test: {report.get('streams')} streams at {report.get('fps')} fps"
        f" for {report.get('duration_s')} s (in flight {report.get('in_flight') or 'free-running'},"
        f" shared memory {'on' if report.get('shared_memory') else 'off'}{warm})",
        f"frames: {report.get('frames_source', 'simulated')}",
        f"{'stream':8} {'published':>9} {'received':>8} {'lost':>5} {'dropped':>7} {'p50 ms':>7}"
        f" {'p95 ms':>7} {'p99 ms':>7} {'max ms':>7} {'gap s':>6} {'yaw jump':>8} {'cluster':>7}"
        f" {'alone':>5} {'warm-up lost':>12}",
    ]
    for s in report.get("per_stream", []):
        lat = s["latency_ms"]
        lines.append(
            f"{s['uav']:8} {s['published']:9d} {s['received']:8d} {s['lost']:5d} {s['reported_dropped']:7d}"
            f" {_f(lat['p50']):>7} {_f(lat['p95']):>7} {_f(lat['p99']):>7} {_f(lat['max']):>7}"
            f" {_f(s['max_gap_s'], 2):>6} {_f(s['max_yaw_jump_deg'], 2):>8}"
            f" {_pct(s.get('cluster_share')):>7} {s.get('frames_master_alone', '-'):>5}"
            f" {_warm(s.get('warmup')):>12}"
        )
    for f in report.get("faults", []):
        lines.append(
            f"fault {f['fault']:22} hit {f['hit'] or '-':18} lost {f['lost']:3d}  gap {_f(f['gap_s'], 2)} s"
            f"  recovery {_f(f['recovery_s'], 2)} s"
            f"  yaw discontinuity {_f(f['yaw_discontinuity_deg'], 2)} deg"
        )
    for o in report.get("objectives", []):
        lines.append(
            f"objective {o['objective']:20} value {_f(o['value'], 3):>9}  {'met' if o['met'] else 'BREACHED'}"
        )
    if "capacity_streams" in report:
        trials = ", ".join(
            f"{n}: {'met' if t['met'] else 'missed'}" for n, t in report["capacity_trials"].items()
        )
        lines.append(f"capacity: {report['capacity_streams']} streams ({trials})")
    for s in report.get("per_stream", []):
        if shares := s.get("share_by_member"):
            text = ", ".join(f"{member} {_pct(share)}" for member, share in shares.items())
            lines.append(f"shares {s['uav']:8} {text}")
    for host, link in report.get("links", {}).items():
        lines.append(
            f"link {host:8} in {link['rx_bytes_per_frame'] / 1e3:9.1f} kB/frame"
            f"  out {link['tx_bytes_per_frame'] / 1e3:9.1f} kB/frame"
        )
    if model := report.get("model"):
        here, fleet = model["this_machine"], model["reference_fleet"]
        lines.append(
            f"model: {here['streams_exact']:.2f} streams predicted here ({here['limited_by']}) against"
            f" {model['measured_streams']} measured (ratio {_f(model['predicted_over_measured'], 2)});"
            f" {fleet['hosts']} hosts x {fleet['cores_per_host']:g} cores on"
            f" {fleet['link_bit_s'] / 1e9:g} Gbit: {fleet['streams']} streams ({fleet['limited_by']}),"
            f" a frame's path {fleet['path_ms']:.1f} ms at low load"
        )
    if report.get("cpu_s"):
        busiest = sorted(report["cpu_s"].items(), key=lambda kv: -kv[1])[:8]
        lines.append("CPU s: " + ", ".join(f"{name} {value:.1f}" for name, value in busiest))
    lines.append(f"SLO {'passed' if report.get('slo_passed') else 'BREACHED'}")
    return "\n".join(lines)


def plot(report: dict[str, Any], path: Path) -> Path | None:
    """Latency over time per stream with fault markers, latency histogram, lost frames, CPU per service."""
    timeline = report.get("timeline")
    if not timeline:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(13, 8))
    ax_t, ax_h, ax_l, ax_c = axes.ravel()
    all_lat = []
    n_lost = 0
    for uav, rows in timeline.items():
        got = [(t, lat) for t, lat in rows if lat is not None]
        lost = [t for t, lat in rows if lat is None]
        if got:
            ax_t.plot([t for t, _ in got], [lat for _, lat in got], ".", ms=2, label=uav)
            all_lat += [lat for _, lat in got]
        ax_l.plot(lost, [uav] * len(lost), "x", ms=5)
        n_lost += len(lost)
    for f in report.get("faults", []):
        if f.get("applied_at_s") is not None:
            for ax in (ax_t, ax_l):
                ax.axvline(f["applied_at_s"], color="red", lw=0.8)
            ax_t.text(f["applied_at_s"], ax_t.get_ylim()[1], f["fault"], rotation=90, va="top", fontsize=7)
    ax_t.set(xlabel="time since start (s)", ylabel="end-to-end latency (ms)", yscale="log", title="latency")
    ax_t.legend(fontsize=7, markerscale=4)
    if all_lat:
        ax_h.hist(all_lat, bins=60)
    ax_h.set(xlabel="latency (ms)", ylabel="frames", yscale="log", title="latency histogram")
    ax_l.set(xlabel="time since start (s)", title="lost frames")
    if n_lost == 0:  # an empty panel reads as a broken plot: say what it means
        n_frames = sum(len(rows) for rows in timeline.values())
        ax_l.text(0.5, 0.5, f"no frame lost\n({n_frames} frames, {len(timeline)} streams)", ha="center",
                  va="center", transform=ax_l.transAxes, fontsize=12)  # fmt: skip
        ax_l.set_yticks([])
    cpu = report.get("cpu_s", {})
    names = sorted(cpu, key=lambda n: -cpu[n])[:12]
    ax_c.barh(names, [cpu[n] for n in names])
    ax_c.set(xlabel="CPU seconds over the run", title="CPU per service")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
