"""CPU time per frame of each role (master, foreman, worker, router) on every dispatch path.

Issue 29's first measure: what dispatching costs, in CPU time (host-independent, unlike latency), for the same
simulated hover: in-process (``YawTracker.track`` under ``time.process_time``), the master alone,
master-worker (1 worker) and master-foreman-worker (1 foreman x 1 worker, and 2 x 2), each flown ``--repeats``
times, interleaved: the table gives every role's median over the repeats, the master's p95 and its median
frame time (frame in to yaw out, wall ms: ``frame_ms``). For a cluster path each process's user + system CPU
time is read from /proc before the camera starts and once the last yaw arrived; its idle rate (keep-alives,
stats), measured over a short window before the flight, is taken off. A role's figure is the sum over its
processes divided by the frames. The camera is left out: it starts with the flight, and its interpreter's
start-up cannot be told apart from its per-frame work. Its frames are rendered once, before any run, and
replayed from memory (``--images --preload``): the in-process run measures the same frames, and a camera
rendering 1080p on the ground host's CPU (about 70 ms of CPU a frame) would take that CPU from the master,
where a UAV's camera is not. The master's share of the in-process cost is the issue's "dispatch cheaper than
compute" figure (target <= 25 %). Shared memory is off (the figures stand for separate hosts). CPU seconds are
not wall time, but a busy host still inflates them (cache, steal) and /proc counts in 10 ms ticks: run it
alone, with enough frames.

Latency against one host: ``--netns --pin`` gives each emulated host one CPU (the ground host, with the
master, the camera and its router, the first; the in-process run the same one) and the table's
``latency_ratio`` is the master's median frame time over the in-process time per frame; ``--master-computes``
lets the master compute a share too, as in the paper. The in-process run is the bare tracker on frames in
memory; path ``0``, the master alone (computing every patch, no members, the camera and its router beside it),
is the one-host deployment as it runs, and each cluster path's ``vs_alone`` its frame time against that one's.

The workload (``--resolution``, ``--grid``, ``--patch-size``, ``--pyramid-level``; unless given, the yaw
core's defaults at 752x480) is the same in-process and on the master. Distributing pays on a heavy frame: the
cluster bench's grid (``--grid 16x12 --patch-size 128 --pyramid-level 0``) at 752x480 and 1920x1080.
"""

from __future__ import annotations

import argparse
import logging
import os
import time
import typing
from collections.abc import Mapping
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from common.dispatch import Balance
from common.members import Topology
from common.wire.frame_codec import MAX_JPEG_QUALITY, MIN_JPEG_QUALITY
from common.wire.jobs import JobEncoding
from common.wire.messages import YawEstimate
from common.yaw import YawSettings
from services.camera.settings import FlightName
from services.master.settings import MasterSettings
from services.runtime.allocator import HeapPolicy, apply_heap_policy, children_heap_policy
from services.runtime.cli import number_in
from services.runtime.transport import open_session
from services.tools.bench.cluster import at_least
from services.tools.bench.dispatch_workload import (
    TURNS_FROM_FRAME,
    flight_frames,
    in_process_cpu_ms,
    workload_of,
)
from services.tools.cluster_file import ClusterSpec, HostSpec, add_deadline_argument, with_deadline
from services.tools.loadtest.harness import processes_cpu_seconds
from services.tools.netns import (
    NetHarness,
    NetnsError,
    link_bytes_per_frame,
    new_prefix,
    unavailable_reason,
)
from services.tools.netns_cluster import GROUND, NetnsCluster, plan_for_cluster
from services.tools.observe import YawCollector, median_timings_ms
from services.tools.up import LocalCluster

NAME = "dispatch"
logger = logging.getLogger(__name__)

#: the master computing every patch, no members: the one-host deployment a cluster must beat
ALONE = "master alone 0"
#: (label, topology, workers per host); the master alone first: the others' ``vs_alone`` is against it
PATHS: tuple[tuple[str, Topology, tuple[int, ...]], ...] = (
    (ALONE, Topology.MASTER_WORKER, ()),
    ("master-worker 1", Topology.MASTER_WORKER, (1,)),
    ("master-foreman-worker 1x1", Topology.MASTER_FOREMAN_WORKER, (1,)),
    ("master-foreman-worker 2x2", Topology.MASTER_FOREMAN_WORKER, (2, 2)),
)
ROLES = ("master", "foreman", "worker", "router")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=at_least(10), default=100, help="frames of each path's flight")
    parser.add_argument(
        "--fps", type=number_in(float, 0.1, 1000.0), default=10.0, help="camera rate (paced: cores not full)"
    )
    parser.add_argument(
        "--repeats",
        type=number_in(int, 1, 50),
        default=3,
        help="flights of each path (median and p95 over them)",
    )
    parser.add_argument(
        "--idle-s", type=number_in(float, 0.1, 600.0), default=3.0, help="window of the idle CPU rate"
    )
    parser.add_argument(
        "--netns", action="store_true", help="each host in its own network namespace (root): bytes per link"
    )
    parser.add_argument(
        "--link-mbit", type=number_in(float, 0.1, 100_000.0), help="with --netns: every link's rate (Mbit/s)"
    )
    parser.add_argument(
        "--master-computes", action="store_true",
        help="the master computes a share too (the paper's configuration; default: it only dispatches)",
    )  # fmt: skip
    parser.add_argument(
        "--pin", action="store_true",
        help="one CPU per host: the ground host (master, camera, its router) and the in-process run on the "
        "first, each member host on one of the others (latency against one host's CPU: latency_ratio)",
    )  # fmt: skip
    add_deadline_argument(parser)
    yaw = YawSettings()  # the workload's defaults are the yaw core's
    workload = parser.add_argument_group("workload (the same for the in-process run and the master)")
    workload.add_argument("--resolution", default="752x480", help="simulated camera WIDTHxHEIGHT")
    workload.add_argument(
        "--flight", choices=[FlightName.HOVER.value, FlightName.TURNS.value], default=FlightName.HOVER.value,
        help="the simulated flight: paper A's hover (18 %% of its first 120 frames turn more than the yaw's "
        f"refine_min_deg) or paper C's turns from frame {TURNS_FROM_FRAME} on (91 %% of the next 200 do; "
        "their second pass runs on the members from the master's --refine-on-members-pixels on)",
    )  # fmt: skip
    workload.add_argument("--grid", default=f"{yaw.grid_cols}x{yaw.grid_rows}", help="patch grid COLSxROWS")
    workload.add_argument(
        "--patch-size", type=number_in(int, 8, 256), default=yaw.patch_size_px, help="patch side at the level"
    )
    workload.add_argument(
        "--pyramid-level", type=number_in(int, 0, 4), default=yaw.pyramid_level, help="pyramid level"
    )
    parser.add_argument(
        "--paths", nargs="+", choices=[label.split()[-1] for label, _, _ in PATHS], metavar="PATH",
        help="only these paths, by their last word: 0 (the master alone, computing every patch: the "
        "one-host deployment), 1 (master-worker), 1x1, 2x2 (default: all)",
    )  # fmt: skip
    parser.add_argument(
        "--heap-policies", nargs="+", choices=[h.value for h in HeapPolicy], metavar="POLICY",
        help="fly every path under each of these C heap policies of the cluster's processes (warm: the "
        "services' default; glibc: glibc trimming its heap itself), interleaved (default: warm)",
    )  # fmt: skip
    parser.add_argument(
        "--job-encoding", choices=typing.get_args(JobEncoding), default=MasterSettings().job_encoding,
        help="the master's --job-encoding (how a share's pixels travel to the members)",
    )  # fmt: skip
    parser.add_argument(
        "--job-quality", type=number_in(int, MIN_JPEG_QUALITY, MAX_JPEG_QUALITY),
        default=MasterSettings().job_quality,
        help="the master's --job-quality (JPEG quality of a share with --job-encoding jpeg)",
    )  # fmt: skip


def role_of(member: str) -> str:
    return member.split("/", 1)[0]


def cpu_ms_per_frame(
    before_s: Mapping[str, float],
    after_s: Mapping[str, float],
    idle_rate: Mapping[str, float],
    flight_s: float,
    frames: int,
) -> dict[str, float]:
    """CPU ms per frame of each role: (after - before - idle rate x flight time) summed over the role's
    processes, / frames; a process missing in either reading or of another role is left out, a negative
    net counts as 0."""
    per_role = dict.fromkeys(ROLES, 0.0)
    for name in before_s.keys() & after_s.keys():
        if (role := role_of(name)) not in per_role:
            continue
        net = after_s[name] - before_s[name] - idle_rate.get(name, 0.0) * flight_s
        per_role[role] += max(0.0, net)
    return {role: 1e3 * seconds / frames for role, seconds in per_role.items()}


def host_cpus() -> tuple[str, list[str]]:
    """``--pin``'s CPU sets: the ground host's (the first CPU) and the member hosts' (the others, or the
    first again on a machine of one CPU)."""
    cores = sorted(os.sched_getaffinity(0))
    return str(cores[0]), [str(c) for c in (cores[1:] or cores)]


def path_spec(
    label: str, topology: Topology, workers: tuple[int, ...], master_computes: bool = False, pin: bool = False
) -> ClusterSpec:
    """One path's cluster; with no member hosts (:data:`ALONE`) the master computes whatever the option."""
    ground, members = host_cpus() if pin else (None, [None])
    return ClusterSpec(
        name=label.replace(" ", "-"),
        topology=topology,
        balance=Balance.TIME,
        master_computes=master_computes or not workers,
        master_cpus=ground,
        aux_cpus=ground,
        hosts=tuple(
            HostSpec(name=f"h{i + 1}", workers=n, cpus=members[i % len(members)])
            for i, n in enumerate(workers)
        ),
    )


def heap_label(label: str, heap: HeapPolicy) -> str:
    """A path's row: its label, and the heap policy where it is not the services' default."""
    return label if heap is HeapPolicy.WARM else f"{label} ({heap.value} heap)"


def cluster_path(
    label: str,
    topology: Topology,
    workers: tuple[int, ...],
    args: argparse.Namespace,
    heap: HeapPolicy = HeapPolicy.WARM,
) -> dict[str, Any]:
    """One path's flight (its processes under ``heap``): on loopback, or (``--netns``) across emulated hosts
    with per-link bytes."""
    spec = with_deadline(
        path_spec(label, topology, workers, args.master_computes, args.pin), args.min_deadline_ms
    )
    if heap is not HeapPolicy.WARM:
        spec = spec.model_copy(update={"name": f"{spec.name}-{heap.value}-heap"})
    with children_heap_policy(heap):
        return {**_cluster_flight(spec, args), "path": heap_label(label, heap), "heap": heap.value}


def _cluster_flight(spec: ClusterSpec, args: argparse.Namespace) -> dict[str, Any]:
    flight_frames(args)
    log_dir = Path(args.out) / "dispatch_logs" / spec.name
    _, _, master_args = workload_of(args)
    if not args.netns:
        with LocalCluster(spec, log_dir, master_args=master_args) as cluster:
            return _flight(cluster, args, None)
    rate = None if args.link_mbit is None else round(args.link_mbit * 1e6)
    plan = plan_for_cluster(spec, new_prefix(), dict.fromkeys([GROUND, *(h.name for h in spec.hosts)], rate))
    with NetHarness(plan) as net, NetnsCluster(spec, log_dir, net, master_args=master_args) as cluster:
        return _flight(cluster, args, net)


def _members(estimates: Mapping[int, YawEstimate]) -> dict[str, int]:
    members: dict[str, int] = {}
    for estimate in estimates.values():
        for member, patches in estimate.members.items():
            members[member] = members.get(member, 0) + patches
    return members


def _flight(cluster: LocalCluster, args: argparse.Namespace, net: NetHarness | None) -> dict[str, Any]:
    """Idle window, then the camera's flight; CPU (and link bytes) read around it; the yaw watched from a
    session of our own (loopback) or from an agent in the ground host (namespaces)."""
    cluster.start()
    cluster.wait_alive(cluster.expected_members())
    timeout_s = 60.0 + 2.0 * args.frames / max(args.fps, 1.0)
    with ExitStack() as stack:
        if isinstance(cluster, NetnsCluster):
            agent = cluster.agent(GROUND, ["yaw", "--count", str(args.frames)], timeout_s)
            agent.wait_ready()

            def outcome() -> tuple[int, dict[str, int], dict[str, float]]:
                got = agent.result(timeout_s + 15.0)
                return len(got["seqs"]), dict(got["members"]), dict(got["median_timings_ms"])
        else:
            session = stack.enter_context(open_session(cluster.observer_transport()))
            collector = YawCollector(session, cluster.spec.uav)
            stack.callback(collector.close)

            def outcome() -> tuple[int, dict[str, int], dict[str, float]]:
                collector.wait_for(args.frames, timeout_s)
                estimates = dict(collector.estimates)
                return len(estimates), _members(estimates), median_timings_ms(estimates.values())

        idle0, t_idle = processes_cpu_seconds(cluster.processes), time.monotonic()
        time.sleep(args.idle_s)  # the idle window itself: a rate, not a wait for a condition
        idle1 = processes_cpu_seconds(cluster.processes)
        idle_s = time.monotonic() - t_idle
        idle_rate = {n: (idle1[n] - idle0[n]) / idle_s for n in idle0.keys() & idle1.keys()}
        before, t0 = processes_cpu_seconds(cluster.processes), time.monotonic()
        bytes0 = net.link_bytes() if net is not None else {}
        cluster.start_camera(["--images", str(args.frame_dir), "--preload", "--fps", str(args.fps),
                              "--in-flight", "1", "--no-sensors"])  # fmt: skip
        received, members, timings = outcome()
        after, flight_s = processes_cpu_seconds(cluster.processes), time.monotonic() - t0
        bytes1 = net.link_bytes() if net is not None else {}
    cluster.stop()
    frames = max(received, 1)
    links = link_bytes_per_frame(bytes0, bytes1, frames)
    return {"frames": received, "lost": args.frames - received,
            "cpu_ms_per_frame": cpu_ms_per_frame(before, after, idle_rate, flight_s, frames),
            # before the idle rate is taken off: what the processes spent, idle polling included
            "gross_cpu_ms_per_frame": cpu_ms_per_frame(before, after, {}, flight_s, frames),
            "patches_by_member": members, "flight_s": flight_s, "links": links,
            # the master's median stage timings (``total``: frame in to yaw out, wall ms)
            "median_timings_ms": timings}  # fmt: skip


def median_p95(values: list[float]) -> tuple[float, float]:
    """Median and 95th percentile of one figure over the repeats."""
    array = np.asarray(values, dtype=np.float64)
    return float(np.median(array)), float(np.percentile(array, 95))


def _frame_ms(path_runs: list[dict[str, Any]]) -> list[float]:
    """Each repeat's median frame time of the master (frame in to yaw out), where it reported one."""
    return [r["median_timings_ms"]["total"] for r in path_runs if "total" in r.get("median_timings_ms", {})]


def summary_table(
    in_process_runs: list[float], in_process_frames: int, runs: Mapping[str, list[dict[str, Any]]]
) -> list[dict[str, Any]]:
    """The table: in-process, then each path with every role's median CPU ms per frame over the repeats, the
    master's p95, its share of the in-process median (median and p95), each host's link kB per frame and,
    where the master alone flew too, ``vs_alone``: the median over the repeats of the path's frame time over
    the master alone's in the same repeat."""
    repeats = len(in_process_runs)
    in_process, in_process_p95 = median_p95(in_process_runs)
    table: list[dict[str, Any]] = [{"path": "in-process", "frames": in_process_frames, "lost": 0,
                                    "in_process_ms": in_process, "master_ms": in_process,
                                    "master_ms_p95": in_process_p95}]  # fmt: skip
    for label, path_runs in runs.items():
        roles = {role: median_p95([r["cpu_ms_per_frame"][role] for r in path_runs]) for role in ROLES}
        share, share_p95 = median_p95([r["cpu_ms_per_frame"]["master"] / in_process for r in path_runs])
        links: dict[str, float] = {}
        for r in path_runs:
            for host, link in r["links"].items():
                links.setdefault(f"{host}_tx_kB", 0.0)
                links[f"{host}_tx_kB"] += link["tx_bytes_per_frame"] / 1e3 / repeats
        frame_ms = _frame_ms(path_runs)
        # the master's frame time (frame in to yaw out) against the in-process tracker's time per frame: the
        # medians' ratio, and the median of each repeat's ratio to the in-process run just before it
        paired = [t / in_process_runs[i] for i, t in enumerate(frame_ms)] if len(frame_ms) == repeats else []
        latency = {"frame_ms": median_p95(frame_ms)[0], "latency_ratio": median_p95(frame_ms)[0] / in_process}
        latency = {**latency, "paired_ratio": median_p95(paired)[0]} if paired else latency
        # the master alone flown under the same heap policy (a flight without one: the services' default)
        alone = heap_label(ALONE, HeapPolicy(path_runs[0].get("heap", HeapPolicy.WARM.value)))
        alone_ms = _frame_ms(runs.get(alone, []))
        if len(alone_ms) == len(frame_ms) == repeats and label != alone:
            latency["vs_alone"] = median_p95([t / a for t, a in zip(frame_ms, alone_ms, strict=True)])[0]
        latency = latency if frame_ms else {}
        table.append({"path": label, "frames": sum(r["frames"] for r in path_runs),
                      "lost": sum(r["lost"] for r in path_runs),
                      **{f"{role}_ms": roles[role][0] for role in ROLES},
                      "master_ms_p95": roles["master"][1],
                      "master_share": share, "master_share_p95": share_p95,
                      **latency, **links})  # fmt: skip
    return table


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.netns and (reason := unavailable_reason()) is not None:
        raise NetnsError(f"--netns: {reason}")
    size, settings, _ = workload_of(args)
    ground_cpu = host_cpus()[0] if args.pin else None
    frames = flight_frames(args)
    repeats = args.repeats
    in_process_runs: list[float] = []
    chosen = [p for p in PATHS if not getattr(args, "paths", None) or p[0].split()[-1] in args.paths]
    heaps = [HeapPolicy(h) for h in getattr(args, "heap_policies", None) or [HeapPolicy.WARM]]
    runs: dict[str, list[dict[str, Any]]] = {heap_label(p[0], h): [] for h in heaps for p in chosen}
    # the in-process run with the services' heap policy (this process's: set once, process-wide)
    apply_heap_policy(HeapPolicy.WARM)
    # repeats interleave the paths, so that a change of the (shared) host's load hits them alike
    for _ in range(repeats):
        in_process_runs.append(in_process_cpu_ms(frames, settings, ground_cpu))
        for heap in heaps:
            for label, topology, workers in chosen:
                runs[heap_label(label, heap)].append(cluster_path(label, topology, workers, args, heap))
    table = summary_table(in_process_runs, repeats * (args.frames - 1), runs)
    in_process = table[0]["in_process_ms"]
    return {
        "table": table,
        "json": {
            "resolution": "{}x{}".format(*size),
            "grid": f"{settings.grid_cols}x{settings.grid_rows}",
            "patch_size_px": settings.patch_size_px,
            "pyramid_level": settings.pyramid_level,
            "netns": args.netns,
            "link_mbit": args.link_mbit,
            "master_computes": args.master_computes,
            "job_encoding": args.job_encoding,
            "job_quality": args.job_quality,
            "heap_policies": [h.value for h in heaps],
            "pinned": args.pin,
            "frames": args.frames,
            "fps": args.fps,
            "repeats": repeats,
            "in_process_cpu_ms_per_frame": in_process,
            "in_process_cpu_ms_per_frame_runs": in_process_runs,
            "paths": [r for path_runs in runs.values() for r in path_runs],
            "target_master_share": 0.25,
        },
    }
