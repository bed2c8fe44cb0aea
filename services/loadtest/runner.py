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

from common import keys
from common.messages import Frame, encode
from services.loadtest.harness import (
    FrameLoop,
    Hostile,
    LoadCluster,
    RunSettings,
    StreamLog,
    YawLog,
    apply_fault,
)
from services.loadtest.plan import (
    FaultOutcome,
    Objective,
    StreamSummary,
    analyse_fault,
    capacity_of,
    evaluate,
    metric_values,
    next_capacity,
    summarise,
)
from services.runtime.transport import open_session
from services.up import ClusterSpec

logger = logging.getLogger(__name__)

#: seconds at the start of a run left out of the latency statistics (first frames: spectra, routes)
SETTLE_S = 2.0
#: longest a stream with frames in flight waits for a yaw before it sends the next frame anyway
IN_FLIGHT_WAIT_S = 2.0


def _progress(t0: float, logs: dict[str, StreamLog], out: Any) -> None:
    sent = sum(len(log.sent) for log in logs.values())
    got = sum(len(log.received) for log in logs.values())
    latest = [
        1e3 * (arrival - log.sent[seq][0])
        for log in logs.values()
        for seq, (arrival, _) in list(log.received.items())[-20:]
    ]
    worst = max(latest, default=float("nan"))
    out.write(
        f"\r  {time.time() - t0:6.1f} s  frames sent {sent:6d}  yaws {got:6d}  recent max {worst:6.1f} ms "
    )
    out.flush()


def run_once(spec: ClusterSpec, settings: RunSettings, log_dir: Path, live: bool = True) -> dict[str, Any]:
    """Run one load test; returns the report (without objectives)."""
    loop = FrameLoop(settings.loop_frames, settings.seed)
    load = LoadCluster(spec, settings, log_dir)
    applied: list[tuple[float, str, str]] = []
    logs = {uav: StreamLog(uav) for uav in load.uavs}
    t0 = 0.0
    try:
        load.start()
        with open_session(load.cluster.observer_transport()) as session, ExitStack() as cameras:
            yaws = YawLog(session, logs)
            publishers = {
                uav: camera.declare_publisher(
                    keys.camera_key(uav), congestion_control=zenoh.CongestionControl.DROP
                )
                for uav, camera in load.camera_sessions(cameras, session).items()
            }
            load.wait_leaders(session)
            hostile = Hostile(session, publishers[load.uavs[0]], spec, load.uavs[0])
            load.mark_cpu()
            t0 = time.time() + 0.2
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
            period = 1.0 / settings.fps
            n = len(load.uavs)
            next_progress = t0 + 1.0
            for k in range(int(settings.duration_s * settings.fps)):
                for i, uav in enumerate(load.uavs):
                    due = t0 + k * period + i * period / n
                    time.sleep(max(0.0, due - time.time()))
                    log = logs[uav]
                    if settings.in_flight and k >= settings.in_flight:
                        awaited = k - settings.in_flight
                        with yaws.lock:
                            yaws.lock.wait_for(lambda: awaited in log.received, IN_FLIGHT_WAIT_S)  # noqa: B023
                    pixels, true_yaw = loop.at(k + 37 * i)
                    stamp = time.time()
                    payload, attachment = encode(
                        Frame(uav=uav, seq=k, stamp_s=stamp, width=pixels.shape[1], height=pixels.shape[0],
                              pixels=pixels)
                    )  # fmt: skip
                    log.sent[k] = (stamp, true_yaw)
                    publishers[uav].put(payload, attachment=attachment)
                if live and time.time() >= next_progress:
                    _progress(t0, logs, sys.stderr)
                    next_progress += 1.0
            stop.set()
            deadline = time.time() + 3.0  # the last yaws
            while time.time() < deadline and any(len(g.received) < len(g.sent) for g in logs.values()):
                time.sleep(0.05)
            if live:
                _progress(t0, logs, sys.stderr)
                sys.stderr.write("\n")
            load.collect_cpu()
            yaws.close()
            for publisher in publishers.values():
                publisher.undeclare()
            injector.join(5.0)
    finally:
        exit_codes = load.stop()
    return _report(settings, logs, applied, t0, load.cpu, exit_codes)


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
        summaries.append(summarise(uav, records, log.reported_dropped, SETTLE_S))
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
        "shared_memory": settings.shared_memory,
        "standby_masters": settings.standby_masters,
        "profile": "secure" if settings.secure_dir else "open",
        "per_stream": [
            {
                "uav": s.uav,
                "published": s.published,
                "received": s.received,
                "lost": s.lost,
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


def judge(report: dict[str, Any], objectives: list[Objective]) -> bool:
    """Add the objectives' verdicts to the report; True when all are met."""
    from services.loadtest.plan import Metric

    values = {Metric(k): float(v) for k, v in report["metrics"].items()}
    verdicts = evaluate(objectives, values)
    report["objectives"] = [
        {"objective": v.objective.label, "value": v.value, "met": v.met} for v in verdicts
    ]
    report["slo_passed"] = all(v.met for v in verdicts)
    return bool(report["slo_passed"])


def capacity_search(
    spec: ClusterSpec, settings: RunSettings, objectives: list[Objective], log_dir: Path, limit: int
) -> dict[str, Any]:
    """The most streams that meet the objectives (doubling, then bisection); every trial's report kept."""
    tried: dict[int, bool] = {}
    trials: dict[int, dict[str, Any]] = {}
    while (n := next_capacity(tried, limit)) is not None:
        logger.info("capacity search: %d streams", n)
        trial = RunSettings(**{**settings.__dict__, "streams": n})
        report = run_once(spec, trial, log_dir / f"streams{n}")
        tried[n] = judge(report, objectives)
        report.pop("timeline", None)
        trials[n] = report
        verdicts = ", ".join(f"{v['objective']}: {v['value']:.3g}" for v in report["objectives"])
        logger.info("capacity search: %d streams %s (%s)", n, "met" if tried[n] else "missed", verdicts)
    capacity = capacity_of(tried)
    best = dict(trials[capacity]) if capacity in trials else {"streams": 0, "metrics": {}}
    best["capacity_streams"] = capacity
    best["capacity_trials"] = {
        str(k): {"met": tried[k], "metrics": v["metrics"]} for k, v in sorted(trials.items())
    }
    best["slo_passed"] = capacity > 0
    return best
