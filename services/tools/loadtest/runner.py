"""One load-test run (cluster up, streams at their rate, faults, yaws collected) and the capacity search."""

from __future__ import annotations

import logging
import sys
import threading
import time
from contextlib import ExitStack
from dataclasses import asdict
from pathlib import Path
from typing import Any

import zenoh

from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import Frame
from services.runtime.transport import open_session
from services.tools.cluster_file import ClusterSpec
from services.tools.loadtest.frames import FrameLoop, recorded_frames, simulated_frames
from services.tools.loadtest.harness import Hostile, LoadCluster, RunSettings, apply_fault
from services.tools.loadtest.hosts import frames_in_window
from services.tools.loadtest.observers import StatsLog, StreamLog, YawLog
from services.tools.loadtest.plan import (
    FaultOutcome,
    Objective,
    StreamSummary,
    analyse_fault,
    capacity_of,
    compute_share,
    evaluate,
    metric_values,
    next_capacity,
    summarise,
    yaw_jumps_deg,
)
from services.tools.netns import NetHarness, link_bytes_per_frame

logger = logging.getLogger(__name__)

#: longest a stream with frames in flight waits for a yaw before it sends the next frame anyway
IN_FLIGHT_WAIT_S = 2.0


def _progress(t0: float, logs: dict[str, StreamLog], out: Any) -> None:
    sent = sum(len(log.sent) + len(log.warm) for log in logs.values())
    got = sum(len(log.received) for log in logs.values())
    latest = [
        1e3 * (arrival - (log.sent.get(seq) or log.warm[seq])[0])
        for log in logs.values()
        for seq, (arrival, _) in list(log.received.items())[-20:]
    ]
    worst = max(latest, default=float("nan"))
    now = time.time() - t0
    clock = f"warm-up {-now:4.1f} s" if now < 0 else f"{now:6.1f} s"
    line = f"  {clock}  frames sent {sent:6d}  yaws {got:6d}  recent max {worst:6.1f} ms"
    # a terminal gets one line redrawn in place; a file or a pipe gets plain lines (no carriage returns)
    out.write(f"\r{line} " if _is_terminal(out) else f"{line}\n")
    out.flush()


def _is_terminal(out: Any) -> bool:
    return bool(getattr(out, "isatty", lambda: False)())


def progress_interval_s(out: Any) -> float:
    """How often the progress line is written: every second on a terminal, every 10 s into a file."""
    return 1.0 if _is_terminal(out) else 10.0


def frame_loop(settings: RunSettings) -> FrameLoop:
    if settings.replay is not None:
        return recorded_frames(settings.replay, settings.replay_uav)
    return simulated_frames(settings.loop_frames, settings.seed)


def run_once(
    spec: ClusterSpec,
    settings: RunSettings,
    log_dir: Path,
    live: bool = True,
    loop: FrameLoop | None = None,
    net: NetHarness | None = None,
) -> dict[str, Any]:
    """Run one load test; returns the report (without objectives).

    Every stream first sends ``warmup_s`` of frames (the streams join one after another over its first
    half); the clock (``t0``: faults, statistics) starts after it, with the same seq numbers going on, so the
    masters, foremen and workers meet the measured frames warm. Warm-up frames are reported apart."""
    loop = loop or frame_loop(settings)
    load = LoadCluster(spec, settings, log_dir, net)
    applied: list[tuple[float, str, str]] = []
    logs = {uav: StreamLog(uav) for uav in load.uavs}
    t0 = 0.0
    counters: dict[str, dict[str, int]] = {}
    try:
        load.start()
        with open_session(load.cluster.observer_transport()) as session, ExitStack() as cameras:
            yaws = YawLog(session, logs)
            stats = StatsLog(session)
            publishers = {
                uav: camera.declare_publisher(
                    keys.camera_key(uav), congestion_control=zenoh.CongestionControl.DROP
                )
                for uav, camera in load.camera_sessions(cameras, session).items()
            }
            load.wait_leaders(session)
            first = logs[load.uavs[0]]
            hostile = Hostile(
                session, publishers[load.uavs[0]], spec, load.uavs[0], loop.shape,
                lambda: max([*first.sent, *first.warm], default=-1) + 1,
            )  # fmt: skip
            load.mark_cpu()
            stats.mark()
            t_start = time.time() + 0.2
            t0 = t_start + settings.warmup_frames / settings.fps
            stop = threading.Event()

            def faults() -> None:
                for fault in settings.faults:
                    if stop.wait(max(0.0, t0 + fault.at_s - time.time())):
                        return
                    try:
                        hit = apply_fault(load, session, fault, hostile)
                    except Exception as exc:  # a fault that cannot be applied is reported, the run goes on
                        logger.error("fault %s failed: %s", fault.label, exc)
                        hit = f"failed: {exc}"
                    applied.append((time.time() - t0, fault.label, hit))

            injector = threading.Thread(target=faults, name="faults", daemon=True)
            injector.start()
            _stream(settings, loop, logs, yaws, publishers, t_start, t0, live)
            stop.set()
            deadline = time.time() + 3.0  # the last yaws
            while time.time() < deadline and any(
                seq not in g.received for g in logs.values() for seq in list(g.sent)[-5:]
            ):
                time.sleep(0.05)
            if live:
                _progress(t0, logs, sys.stderr)
                sys.stderr.write("\n")
            load.collect_cpu()
            # one more stats message from every service: the counters of the whole run (a fixed 1.2 s
            # missed the master's on a loaded host, and the report lacked its counters)
            stats.wait_fresh(time.monotonic(), timeout_s=5.0)  # a killed service never sends again
            counters = stats.since_mark()
            stats.close()
            yaws.close()
            for publisher in publishers.values():
                publisher.undeclare()
            injector.join(5.0)
    finally:
        exit_codes = load.stop()
    report = _report(settings, logs, applied, t0, load.cpu, exit_codes)
    report["counters"] = counters
    if net is not None:
        report["links"] = link_bytes_per_frame(load.links_before, load.links_after, frames_in_window(report))
    report["frames_source"] = loop.source
    report["recorded_fps"] = loop.recorded_fps
    return report


def _stream(
    settings: RunSettings,
    loop: FrameLoop,
    logs: dict[str, StreamLog],
    yaws: YawLog,
    publishers: dict[str, Any],
    t_start: float,
    t0: float,
    live: bool,
) -> None:
    """Send every stream's frames at its rate (the streams interleaved within each period), warm-up first;
    each frame declares its sender (zenoh ``source_info``) as the camera service does."""
    period = 1.0 / settings.fps
    n = len(logs)
    n_warm = settings.warmup_frames
    first = [settings.first_frame(i) for i in range(n)]
    next_progress = t_start + 1.0
    for k in range(n_warm + int(settings.duration_s * settings.fps)):
        for i, (uav, log) in enumerate(logs.items()):
            if k < first[i]:
                continue
            due = t_start + k * period + i * period / n
            time.sleep(max(0.0, due - time.time()))
            if settings.in_flight and k - settings.in_flight >= first[i]:
                awaited = k - settings.in_flight
                with yaws.lock:
                    yaws.lock.wait_for(lambda: awaited in log.received, IN_FLIGHT_WAIT_S)  # noqa: B023
            pixels, true_yaw = loop.at(k + 37 * i)
            sent = time.time()
            # stamped with its capture time (when it was due): a harness that fell behind and sends a burst
            # must not make the frames look 1 ms apart (the yaw's rate limit trusts stamps); the latency
            # runs from the send, so the harness's own delay is not charged to the cluster
            payload, attachment = encode(
                Frame(uav=uav, seq=k, stamp_s=min(due, sent), width=pixels.shape[1], height=pixels.shape[0],
                      pixels=pixels)
            )  # fmt: skip
            (log.sent if k >= n_warm else log.warm)[k] = (sent, true_yaw)
            publisher = publishers[uav]
            publisher.put(payload, attachment=attachment, source_info=zenoh.SourceInfo(publisher.id, k))
        if live and time.time() >= next_progress:
            _progress(t0, logs, sys.stderr)
            next_progress += progress_interval_s(sys.stderr)


def _report(
    settings: RunSettings,
    logs: dict[str, StreamLog],
    applied: list[tuple[float, str, str]],
    t0: float,
    cpu: dict[str, float],
    exit_codes: dict[str, int | None],
) -> dict[str, Any]:
    summaries: list[StreamSummary] = []
    outcomes: list[list[FaultOutcome]] = []
    ends = ([f.at_s for f in settings.faults[1:]] + [settings.duration_s + 5.0])[: len(settings.faults)]
    for uav, log in logs.items():
        records = log.records()
        summaries.append(summarise(uav, records, log.reported_dropped, settle_s=0.0))
        outcomes.append(
            [analyse_fault(records, f, t0, t0 + end) for f, end in zip(settings.faults, ends, strict=True)]
        )
    timeline = {
        uav: [
            [
                round(r.sent_s - t0, 4),
                None if r.received_s is None else round(1e3 * (r.received_s - r.sent_s), 3),
            ]
            for r in log.records()
        ]
        for uav, log in logs.items()
    }
    return {
        "streams": settings.streams,
        "fps": settings.fps,
        "duration_s": settings.duration_s,
        "in_flight": settings.in_flight,
        "warmup_s": settings.warmup_s,
        "warmup_ramp_s": settings.first_frame(settings.streams - 1) / settings.fps,
        "shared_memory": settings.shared_memory,
        "standby_masters": settings.standby_masters,
        "profile": "secure" if settings.secure_dir else "open",
        "per_stream": [
            {
                "uav": s.uav,
                "published": s.published,
                "received": s.received,
                "lost": s.lost,
                "warmup": _warmup(logs[s.uav]),
                "reported_dropped": s.reported_dropped,
                "duplicates": logs[s.uav].duplicates,
                "latency_ms": {
                    "p50": s.latency.p50,
                    "p95": s.latency.p95,
                    "p99": s.latency.p99,
                    "max": s.latency.max,
                },
                "max_gap_s": s.max_gap_s,
                "max_yaw_jump_deg": s.max_yaw_jump_deg,
                # the three largest, to find them in the timeline: [seconds since the clock, deg]
                "worst_yaw_jumps": [
                    [round(t - t0, 3), round(j, 3)]
                    for t, j in sorted(yaw_jumps_deg(logs[s.uav].records()), key=lambda tj: -tj[1])[:3]
                ],
                **_computed(logs[s.uav]),
            }
            for s in summaries
        ],
        "faults": [
            {
                "fault": f.label,
                "applied_at_s": next((round(t, 3) for t, label, _ in applied if label == f.label), None),
                "hit": next((hit for _, label, hit in applied if label == f.label), None),
                "per_stream": [
                    {"uav": s.uav, **{k: v for k, v in asdict(o).items() if k != "fault"}}
                    for s, o in zip(summaries, (per[i] for per in outcomes), strict=True)
                ],
                "lost": max(per[i].lost for per in outcomes),
                "gap_s": max(per[i].gap_s for per in outcomes),
                "recovery_s": max(per[i].recovery_s for per in outcomes),
                "yaw_discontinuity_deg": max(per[i].yaw_discontinuity_deg for per in outcomes),
            }
            for i, f in enumerate(settings.faults)
        ],
        "metrics": {m.value: v for m, v in metric_values(summaries, outcomes).items()},
        "cpu_s": cpu,
        "exit_codes": exit_codes,
        "timeline": timeline,
    }


def _warmup(log: StreamLog) -> dict[str, int]:
    """What the warm-up sent and lost (not in the statistics; shown so that nothing is hidden)."""
    records = log.records(warm_up=True)
    return {"published": len(records), "lost": sum(1 for r in records if r.received_s is None)}


def _computed(log: StreamLog) -> dict[str, Any]:
    share = compute_share(v for seq, v in log.computed.items() if seq in log.sent)  # the measured frames
    return {
        "computed_frames": share.frames,
        "frames_master_alone": share.frames_alone,
        "cluster_share": round(share.cluster_share, 4),
        "share_by_member": {m: round(v, 4) for m, v in share.by_member.items()},
    }


def judge(report: dict[str, Any], objectives: list[Objective]) -> bool:
    """Add the objectives' verdicts to the report; True when all are met."""
    from services.tools.loadtest.plan import Metric

    values = {Metric(k): float(v) for k, v in report["metrics"].items()}
    verdicts = evaluate(objectives, values)
    report["objectives"] = [
        {"objective": v.objective.label, "value": v.value, "met": v.met} for v in verdicts
    ]
    report["slo_passed"] = all(v.met for v in verdicts)
    return bool(report["slo_passed"])


def capacity_search(
    spec: ClusterSpec,
    settings: RunSettings,
    objectives: list[Objective],
    log_dir: Path,
    limit: int,
    net: NetHarness | None = None,
) -> dict[str, Any]:
    """The most streams that meet the objectives (doubling, then bisection); every trial's report kept."""
    tried: dict[int, bool] = {}
    trials: dict[int, dict[str, Any]] = {}
    loop = frame_loop(settings)
    while (n := next_capacity(tried, limit)) is not None:
        logger.info("capacity search: %d streams", n)
        trial = RunSettings(**{**settings.__dict__, "streams": n})
        report = run_once(spec, trial, log_dir / f"streams{n}", loop=loop, net=net)
        tried[n] = judge(report, objectives)
        report.pop("timeline", None)
        trials[n] = report
        verdicts = ", ".join(f"{v['objective']}: {v['value']:.3g}" for v in report["objectives"])
        logger.info("capacity search: %d streams %s (%s)", n, "met" if tried[n] else "missed", verdicts)
    capacity = capacity_of(tried)
    best = (
        dict(trials[capacity])
        if capacity in trials
        else {
            "streams": 0,
            "fps": settings.fps,
            "duration_s": settings.duration_s,
            "warmup_s": settings.warmup_s,
            "metrics": {},
        }
    )
    best["capacity_streams"] = capacity
    best["capacity_trials"] = {
        str(k): {"met": tried[k], "metrics": v["metrics"], "frames": frames_in_window(v), "cpu_s": v["cpu_s"],
                 **({"links": v["links"]} if "links" in v else {})}
        for k, v in sorted(trials.items())
    }  # fmt: skip
    best["slo_passed"] = capacity > 0
    return best
