"""``capataz loadtest``: N simulated UAV streams through a local cluster, faults, objectives, a report.

Examples::

    capataz loadtest --streams 4 --duration 60 --name four
    capataz loadtest --streams 1 --standby --fault kill:worker@20s --fault stop:foreman@30s+6s \\
        --fault kill:router@40s --fault kill:master@50s --duration 70 --name faults
    capataz loadtest --capacity --max-streams 10 --duration 30 --name capacity
    capataz loadtest --hosts 2 --capacity --max-streams 8 --duration 20 --name hosts2
    capataz loadtest --replay out/flight.mcap --streams 4 --duration 30 --name replay
    capataz loadtest --streams 2 --standby --fault kill:master@10s --duration 20 --secure --name secure
"""

from __future__ import annotations

import argparse
import logging
import math
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from services.runtime.usage import number_in
from services.tools.cluster_file import ClusterSpec, add_deadline_argument, load_cluster, with_deadline
from services.tools.loadtest.harness import RunSettings
from services.tools.loadtest.hosts import model_report, spec_for_hosts
from services.tools.loadtest.plan import (
    CAPACITY_OBJECTIVES,
    DEFAULT_OBJECTIVES,
    FAULT_OBJECTIVES,
    Fault,
    LoadtestError,
    parse_objective,
    parse_schedule,
)
from services.tools.loadtest.report import plot, table, write_json
from services.tools.netns import NetHarness, new_prefix, unavailable_reason
from services.tools.netns_cluster import GROUND, plan_for_cluster
from services.tools.secure import add_profile_arguments

logger = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "loadtest",
        help="drive a local cluster with N simulated UAV streams, inject faults, check objectives",
        description="N simulated UAV streams through a local cluster, faults, objectives (SLOs), a report "
        "(out/loadtest/<name>.json and .png). Exit code 2 when an objective is breached.",
        epilog="examples:\n" + __doc__.split("Examples::", 1)[1].rstrip(),
    )
    parser.add_argument(
        "--cluster", type=Path, default=Path("deploy/clusters/loadtest.yml"), help="cluster file"
    )
    parser.add_argument(
        "--streams", type=number_in(int, 1, 256), default=4, help="UAV streams (752x480 camera each)"
    )
    parser.add_argument(
        "--fps",
        type=number_in(float, 0.1, 200.0),
        help="frames per second of each stream (default 20, a replay: its recorded rate)",
    )
    parser.add_argument(
        "--duration", type=number_in(float, 0.1, 3600.0), default=30.0, help="seconds of streaming (measured)"
    )
    parser.add_argument(
        "--warmup", type=number_in(float, 0.0, 600.0), default=4.0,
        help="seconds every stream sends before the clock starts, joining one after another over its first "
        "half (reported apart, not in the statistics; 0: measure from the first frame)",
    )  # fmt: skip
    parser.add_argument(
        "--replay", type=Path, metavar="FILE.mcap",
        help="send the frames of a recording (capataz record) on every stream, stamped with the wall clock",
    )  # fmt: skip
    parser.add_argument("--replay-uav", help="the recording's UAV stream (default: its only one)")
    parser.add_argument(
        "--in-flight",
        type=number_in(int, 0),
        default=0,
        help="frames a stream may have without a yaw (0: free-running)",
    )
    parser.add_argument("--standby", action="store_true", help="a standby master per UAV (fail-over)")
    parser.add_argument("--shm", action="store_true", help="zenoh shared memory on (off: stands for hosts)")
    parser.add_argument(
        "--fault", action="append", default=[], metavar="FAULT",
        help="kill:worker@20s, stop:foreman@30s+6s, kill:router@40s, kill:master@50s, hostile:seq@10s "
        "(hostile kinds: seq, restart, size, uav, future, settings, streams, sender); repeatable",
    )  # fmt: skip
    parser.add_argument("--schedule", type=Path, help="a file of faults (one or more per line, # comments)")
    parser.add_argument(
        "--slo", action="append", default=[], metavar="OBJECTIVE",
        help="p99_ms<=50, lost_pct<0.1, gap_s<=0.5, yaw_jump_deg<=1, lost_per_fault<=1 (repeatable; defaults "
        "depend on the mode)",
    )  # fmt: skip
    parser.add_argument(
        "--capacity", action="store_true", help="search the most streams meeting the objectives"
    )
    parser.add_argument(
        "--max-streams", type=number_in(int, 1, 256), default=16, help="upper bound of the capacity search"
    )
    parser.add_argument(
        "--hosts", type=number_in(int, 1, 16),
        help="run the cluster as N emulated network hosts (namespaces; root): each shaped like the file's "
        "first host, masters only dispatching on a ground host; the report gains bytes per link and, with "
        "--capacity, the capacity model's prediction",
    )  # fmt: skip
    parser.add_argument(
        "--link-mbit", type=number_in(float, 0.1, 100_000.0),
        help="with --hosts: every host's link rate in Mbit/s (token bucket; default: not limited)",
    )  # fmt: skip
    parser.add_argument(
        "--thin-host-mbit", type=number_in(float, 0.1, 100_000.0),
        help="with --hosts: the last host's link rate in Mbit/s (a radio link: the report's shares show the "
        "balancer moving work away from it)",
    )  # fmt: skip
    parser.add_argument(
        "--slow-host-factor", type=number_in(int, 1, 100), default=1,
        help="with --hosts: the last host's workers do their work N times (a slower CPU: the report's shares "
        "show the balancer moving work away from it)",
    )  # fmt: skip
    add_deadline_argument(parser)
    parser.add_argument("--name", default="loadtest", help="report name: out/loadtest/<name>.json/.png")
    parser.add_argument("--out", type=Path, default=Path("out/loadtest"), help="output folder")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated flight")
    add_profile_arguments(parser)
    parser.set_defaults(handler=run)


def _hosts_spec(args: argparse.Namespace, spec: ClusterSpec, faults: tuple[Fault, ...]) -> ClusterSpec:
    """The cluster as ``--hosts`` emulated hosts, or one clear error why it cannot run here."""
    if args.secure is not None:
        raise LoadtestError("--hosts runs the open profile (the secure profile's certificates name loopback)")
    if any(f.target == "router" for f in faults):
        raise LoadtestError("--hosts: a router fault is not supported (each host has its own router)")
    if (reason := unavailable_reason()) is not None:
        raise LoadtestError(f"--hosts needs network namespaces: {reason}")
    return spec_for_hosts(spec, args.hosts, args.slow_host_factor)


def run(args: argparse.Namespace) -> int:
    """Exit code 0 when every objective is met, 2 when one is breached (1: the run itself failed)."""
    from services.tools.loadtest.frames import recorded_frames
    from services.tools.loadtest.runner import capacity_search, judge, run_once

    # a replay is checked before any process starts: a file that is not a recording is one clear error
    recorded = recorded_frames(args.replay, args.replay_uav, 8).recorded_fps if args.replay else math.nan
    if args.fps is None:
        args.fps = recorded if math.isfinite(recorded) else 20.0
    if args.streams < 1 or args.max_streams < 1 or not 0 < args.fps <= 200 or not 0 < args.duration <= 3600:
        raise LoadtestError(
            "--streams/--max-streams must be >= 1, --fps in (0, 200], --duration in (0, 3600]"
        )
    if not 0 <= args.warmup <= 600:
        raise LoadtestError("--warmup must be in [0, 600] s")
    if args.in_flight < 0:
        raise LoadtestError("--in-flight must be >= 0")
    items = list(args.fault)
    if args.schedule is not None:
        try:
            items += args.schedule.read_text().splitlines()
        except OSError as exc:
            raise LoadtestError(f"--schedule: {exc}") from None
    faults = parse_schedule(items)
    if faults and faults[-1].at_s >= args.duration:
        raise LoadtestError(f"fault {faults[-1].label} is after the end of the run ({args.duration:g} s)")
    defaults = CAPACITY_OBJECTIVES if args.capacity else FAULT_OBJECTIVES if faults else DEFAULT_OBJECTIVES
    objectives = [parse_objective(o) for o in (args.slo or defaults)]
    spec = with_deadline(load_cluster(args.cluster), args.min_deadline_ms)
    if args.hosts is not None:
        spec = _hosts_spec(args, spec, faults)
    elif args.link_mbit is not None or args.thin_host_mbit is not None or args.slow_host_factor != 1:
        raise LoadtestError("--link-mbit, --thin-host-mbit and --slow-host-factor need --hosts")
    settings = RunSettings(
        streams=args.streams, fps=args.fps, duration_s=args.duration, in_flight=args.in_flight,
        standby_masters=args.standby or any(f.target == "master" for f in faults), shared_memory=args.shm,
        seed=args.seed, faults=faults, warmup_s=args.warmup, replay=args.replay, replay_uav=args.replay_uav,
        secure_dir=args.secure, zenoh_config=args.zenoh_config,
    )  # fmt: skip
    log_dir = args.out / f"{args.name}-logs"
    link_bit_s = None if args.link_mbit is None else args.link_mbit * 1e6
    with ExitStack() as stack:
        net = None
        if args.hosts is not None:
            rates = dict.fromkeys([GROUND, *(h.name for h in spec.hosts)], None if link_bit_s is None
                                  else int(link_bit_s))  # fmt: skip
            if args.thin_host_mbit is not None:
                rates[spec.hosts[-1].name] = round(args.thin_host_mbit * 1e6)
            net = stack.enter_context(NetHarness(plan_for_cluster(spec, new_prefix(), rates)))
            stack.enter_context(net.joined(GROUND))  # left before the harness removes the namespaces
        if args.capacity:
            report = capacity_search(spec, settings, objectives, log_dir, args.max_streams, net)
        else:
            report = run_once(spec, settings, log_dir, net=net)
            judge(report, objectives)
    # the model takes one link rate and one CPU for every member host: not stated with a thin or slow host
    uniform = args.thin_host_mbit is None and args.slow_host_factor == 1
    if args.capacity and report["capacity_streams"] > 0 and uniform:
        workers = sum(h.workers for h in spec.hosts)
        report["model"] = model_report(report, args.fps, len(spec.hosts), link_bit_s, workers)
    report["name"] = args.name
    report["cluster"] = spec.name
    report["hosts"] = args.hosts
    report["thin_host_mbit"] = args.thin_host_mbit
    report["slow_host_factor"] = args.slow_host_factor
    figure = plot(report, args.out / f"{args.name}.png")
    path = write_json(report, args.out / f"{args.name}.json")
    print(table(report))
    print(f"report: {path}" + (f", figure: {figure}" if figure else ""))
    return 0 if report["slo_passed"] else 2
