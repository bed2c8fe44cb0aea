"""``capataz loadtest --hosts N``: the cluster's hosts as emulated network hosts, what a stream's frame costs
on them, and the capacity model (:mod:`common.capacity`) set against the measured capacity.

The cluster file's first host is the shape of every host (``h1`` ... ``hN``, each a foreman and its workers
in a namespace of its own); the masters only dispatch, on the ground host, with the load test's own
process, which publishes the cameras' frames and watches the yaw (it joins the ground host's namespace).
A run's report gains ``links`` (bytes per frame on each host's link) and, for a capacity search, ``model``:
the streams :func:`~common.capacity.predict` gives for this machine from the costs measured in the search's
trials, beside the capacity the search measured, and its prediction for a fleet (:func:`model_report`).
"""

from __future__ import annotations

import os
from dataclasses import asdict, replace
from typing import Any

from common.capacity import Fleet, Prediction, StreamCost, predict
from common.members import Topology
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.loadtest.harness import HARNESS

#: the fleet ``docs/`` states a prediction for: 10 hosts of 16 cores on 1 Gbit links (ground host: 16 cores)
REFERENCE_FLEET = Fleet(hosts=10, cores_per_host=16.0, ground_cores=16.0, link_bit_s=1e9)


def spec_for_hosts(spec: ClusterSpec, hosts: int, slow_factor: int = 1) -> ClusterSpec:
    """``hosts`` hosts shaped like the file's first, masters that only dispatch (the paper's roles); the last
    host's workers do their work ``slow_factor`` times (a slower CPU, made real in software)."""
    first = spec.hosts[0]
    shaped = tuple(
        HostSpec(
            name=f"h{i + 1}", workers=first.workers, foreman_computes=first.foreman_computes,
            cpu_factor=slow_factor if i == hosts - 1 else first.cpu_factor,
        )
        for i in range(hosts)
    )  # fmt: skip
    return spec.model_copy(
        update={
            "name": f"{spec.name}-{hosts}hosts",
            "hosts": shaped,
            "master_computes": False,
            "topology": Topology.MASTER_FOREMAN_WORKER,
            "master_cpus": None,
            "aux_cpus": None,
        }
    )


def frames_in_window(report: dict[str, Any]) -> int:
    """Frames published while CPU and bytes were counted (warm-up included: the window spans it)."""
    return sum(int(s["published"]) + int(s["warmup"]["published"]) for s in report["per_stream"])


def _role_cpu_s(cpu_s: dict[str, float]) -> dict[str, float]:
    """CPU seconds per role: master, foreman, worker, the ground's router, the members' routers, and this
    process (the cameras' frames and the watchers)."""
    roles: dict[str, float] = {}
    for name, seconds in cpu_s.items():
        role, _, rest = name.partition("/")
        if role == "router":
            role = "ground router" if rest.startswith("ground/") else "member router"
        roles[role] = roles.get(role, 0.0) + float(seconds)
    return roles


def stream_cost(
    cpu_s: dict[str, float], links: dict[str, dict[str, float]], frames: int, fps: float
) -> StreamCost:
    """One stream's cost per frame from a run's CPU seconds per process and bytes per frame per link (none:
    0 bytes) over ``frames`` frames (all streams together)."""
    roles = {role: 1e3 * s / max(frames, 1) for role, s in _role_cpu_s(cpu_s).items()}
    ground = links.get("ground", {"rx_bytes_per_frame": 0.0, "tx_bytes_per_frame": 0.0})
    members = [v for host, v in links.items() if host != "ground"]
    return StreamCost(
        fps=fps,
        ground_cpu_ms=roles.get("master", 0.0) + roles.get("ground router", 0.0),
        member_cpu_ms=sum(roles.get(r, 0.0) for r in ("foreman", "worker", "member router")),
        source_cpu_ms=roles.get(HARNESS, 0.0),
        ground_bytes=ground["rx_bytes_per_frame"] + ground["tx_bytes_per_frame"],
        member_bytes=sum(v["rx_bytes_per_frame"] + v["tx_bytes_per_frame"] for v in members),
        master_cpu_ms=roles.get("master", 0.0),
        foreman_cpu_ms=roles.get("foreman", 0.0),
        worker_cpu_ms=roles.get("worker", 0.0),
    )


def _prediction(p: Prediction) -> dict[str, Any]:
    return {
        "streams": p.streams,
        "streams_exact": round(p.streams_exact, 3),
        "limited_by": p.limited_by.value,
        "use_per_stream": {r.value: round(u, 5) for r, u in p.use_per_stream.items()},
        "path_ms": round(p.path_ms, 2),
    }


def model_report(
    best: dict[str, Any],
    fps: float,
    hosts: int,
    link_bit_s: float | None,
    workers_per_frame: int = 1,
    cores: int | None = None,
) -> dict[str, Any]:
    """The model against the capacity search: each trial that met its objectives gives a stream's cost per
    frame; the one with the most streams (the nearest to the load the capacity is) is predicted for this
    machine (one pool of ``cores`` that every process shares) and for :data:`REFERENCE_FLEET`. The check
    compares the prediction before rounding down with the measured capacity (a count of 3 or 4 streams is
    too coarse to compare rounded)."""
    trials = best["capacity_trials"]
    here = Fleet(
        hosts=hosts, cores_per_host=1.0, ground_cores=1.0, link_bit_s=link_bit_s,
        shared_cores=float(cores or os.cpu_count() or 1),
    )  # fmt: skip

    def cost_of(trial: dict[str, Any]) -> StreamCost:
        cost = stream_cost(trial["cpu_s"], trial.get("links", {}), int(trial["frames"]), fps)
        return replace(cost, workers_per_frame=max(workers_per_frame, 1))

    met = sorted((int(n) for n, t in trials.items() if t["met"]), reverse=True)
    if not met:
        return {}
    cost = cost_of(trials[str(met[0])])
    predicted = predict(cost, here)
    measured = int(best["capacity_streams"])
    return {
        "cost_per_frame": {
            **{k: round(v, 3) for k, v in asdict(cost).items() if k.endswith("_ms")},
            "ground_bytes": round(cost.ground_bytes),
            "member_bytes": round(cost.member_bytes),
            "from_trial_streams": met[0],
        },
        "max_utilisation": here.max_utilisation,
        "this_machine": _prediction(predicted),
        "measured_streams": measured,
        "predicted_over_measured": round(predicted.streams_exact / measured, 3) if measured else None,
        "predicted_by_trial": {
            n: round(predict(cost_of(trials[str(n)]), here).streams_exact, 3) for n in met
        },
        "reference_fleet": {
            "hosts": REFERENCE_FLEET.hosts,
            "cores_per_host": REFERENCE_FLEET.cores_per_host,
            "link_bit_s": REFERENCE_FLEET.link_bit_s,
            **_prediction(predict(cost, REFERENCE_FLEET)),
        },
    }
