"""Allocator: a worker's patch compute under each C allocator policy a member process could run.

The policy decided how a worker and a foreman keep within their memory budget
(:mod:`services.runtime.allocator`). Each policy runs in a process of its own (the allocator's settings are
process-wide): the worker's core (:func:`~common.yaw.patchwork.measure_share`, spectra cached between frames
as in the service) measures the same share of a simulated flight's frames, job after job, and each job's wall
time, minor page faults and the process's peak resident memory are read. Policies:

- ``glibc``: the C library as it comes (its mmap threshold raises itself to the largest block freed);
- ``mmap_1mb``: the threshold fixed at 1 MB (the policy before: every array of 1 MB or more is a fresh
  mapping, faulted in and zeroed on first touch);
- ``heap_trim``: glibc as it comes, and the freed heap pages handed back after a job when resident memory
  exceeds the worker's mark (:class:`~services.runtime.allocator.HeapTrim`; the services' policy before);
- ``warm_heap``: the same, with glibc no longer trimming its heap's top by itself
  (:data:`~services.runtime.allocator.HeapPolicy.WARM`, the services' policy);
- ``trim_every_job``: the same with a mark below any process, so every job trims (its cost where a process
  is over its mark).

Repeats interleave the policies; the table gives each one's median ms per patch (p95 over all jobs), its
median page faults per job, its peak resident MB and its time over ``glibc``'s in the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from services.runtime.cli import number_in, parse_size

NAME = "allocator"
POLICIES = ("glibc", "mmap_1mb", "heap_trim", "warm_heap", "trim_every_job")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--jobs", type=number_in(int, 4, 10_000), default=30, help="jobs per policy and repeat"
    )
    parser.add_argument("--patches", type=number_in(int, 1, 192), default=30, help="patches of a job's share")
    parser.add_argument("--repeats", type=number_in(int, 1, 50), default=3, help="runs of each policy")
    parser.add_argument("--resolution", default="1920x1080", help="simulated camera WIDTHxHEIGHT")
    parser.add_argument("--patch-size", type=number_in(int, 8, 256), default=128, help="patch side (px)")


def after_job_hook(policy: str) -> Callable[[], object]:
    """Set this process's allocator to ``policy``; what to call after each job."""
    from services.runtime.allocator import HEAP_POLICY_ENV, M_MMAP_THRESHOLD, HeapPolicy, HeapTrim, mallopt
    from services.worker.service import WorkerSettings, heap_mark_mb

    if policy == "mmap_1mb":
        mallopt(M_MMAP_THRESHOLD, 1 << 20)
    if policy == "heap_trim":
        return HeapTrim(heap_mark_mb(WorkerSettings())).after_job
    if policy == "warm_heap":  # what a worker does at its start
        environ = {**os.environ, HEAP_POLICY_ENV: HeapPolicy.WARM.value}
        return HeapTrim.for_service(heap_mark_mb(WorkerSettings()), environ).after_job
    if policy == "trim_every_job":
        return HeapTrim(1e-6).after_job
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}: one of {POLICIES}")
    return lambda: None


def measure_jobs(
    policy: str, jobs: int, patches: int, size: tuple[int, int], patch_px: int
) -> dict[str, Any]:
    """One policy's run in this process: per job, ms per patch and minor page faults; the peak RSS (MB)."""
    from common.yaw import YawSettings, make_patch_grid
    from common.yaw.patchwork import SpectrumCache, measure_share
    from services.camera import CameraSettings, simulated_flight

    hook = after_job_hook(policy)
    settings = replace(YawSettings(), grid_cols=16, grid_rows=12, patch_size_px=patch_px, pyramid_level=0)
    flight = simulated_flight(CameraSettings(frames=4, width=size[0], height=size[1]))
    grid = make_patch_grid(flight.frame(0).shape, settings)
    indices = grid.all_indices[-patches:]
    crops = [grid.crop(flight.frame(i), indices) for i in range(4)]
    cache = SpectrumCache()
    measure_share(cache, settings, "s", 0, -1, indices, crops[0], indices, crops[0])
    ms, faults = [], []
    for seq in range(1, jobs + 1):
        f0, t0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt, time.perf_counter()
        measure_share(cache, settings, "s", seq, seq - 1, indices, crops[seq % 4], indices[:0], crops[0][:0])
        hook()
        ms.append((time.perf_counter() - t0) * 1e3 / patches)
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"policy": policy, "ms_per_patch": ms[2:], "faults_per_job": faults[2:], "peak_rss_mb": peak_mb}


def run_policy(policy: str, args: argparse.Namespace) -> dict[str, Any]:
    """:func:`measure_jobs` in a fresh interpreter (a policy is process-wide)."""
    command = [sys.executable, "-m", __name__, policy, str(args.jobs), str(args.patches), args.resolution,
               str(args.patch_size)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, check=False, timeout=1800)
    if done.returncode != 0:
        raise RuntimeError(f"allocator bench child {policy}: {done.stderr.strip().splitlines()[-1:]}")
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def run(args: argparse.Namespace) -> dict[str, Any]:
    parse_size(args.resolution, "--resolution", "1920x1080")
    runs: dict[str, list[dict[str, Any]]] = {p: [] for p in POLICIES}
    for _ in range(args.repeats):  # interleaved: a change of the shared host's load hits every policy
        for policy in POLICIES:
            runs[policy].append(run_policy(policy, args))
    table = []
    for policy, policy_runs in runs.items():
        ms = np.concatenate([r["ms_per_patch"] for r in policy_runs])
        medians = [float(np.median(r["ms_per_patch"])) for r in policy_runs]
        faults = np.concatenate([r["faults_per_job"] for r in policy_runs])
        table.append({"policy": policy, "ms_per_patch": float(np.median(medians)),
                      "ms_per_patch_p95": float(np.percentile(ms, 95)),
                      "faults_per_job": float(np.median(faults)),
                      "peak_rss_mb": max(r["peak_rss_mb"] for r in policy_runs)})  # fmt: skip
    base = table[0]["ms_per_patch"]
    for row in table:
        row["vs_glibc"] = row["ms_per_patch"] / base
    return {
        "table": table,
        "json": {"jobs": args.jobs, "patches": args.patches, "repeats": args.repeats,
                 "resolution": args.resolution, "patch_size_px": args.patch_size, "runs": runs},
    }  # fmt: skip


if __name__ == "__main__":
    policy, jobs, patches, resolution, patch_px = sys.argv[1:6]
    size = parse_size(resolution, "resolution", "1920x1080")
    print(json.dumps(measure_jobs(policy, int(jobs), int(patches), size, int(patch_px))))
