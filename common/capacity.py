"""How many streams a cluster carries: a capacity model from what one stream's frame costs, measured.

A frame of one stream costs CPU on the ground host (the master, the ground's router, the camera's publishing)
and on the member hosts (foremen, workers, their routers), and bytes on the ground host's link and on the
member hosts' links (:class:`StreamCost`, measured by ``capataz loadtest --hosts``). A :class:`Fleet` says
what there is: hosts, cores, link rates, or one pool of cores that every process shares (the emulated hosts
of one machine). Each resource carries ``max_utilisation`` of its capacity before latency objectives break
(queues grow as ``1 / (1 - rho)``); the streams a fleet carries are the fewest any resource allows
(:func:`predict`). Streams are spread evenly over the member hosts.

The latency is the frame's critical path at low load: the master's CPU, a foreman's, the workers' share run
side by side, and the frame's bytes crossing the ground host's link once; queues add to it as the load nears
the ceiling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

from common.errors import InputError

__all__ = ["Fleet", "Prediction", "Resource", "StreamCost", "predict"]


class Resource(StrEnum):
    """What limits the streams."""

    SHARED_CPU = "shared cpu"
    GROUND_CPU = "ground cpu"
    MEMBER_CPU = "member cpu"
    GROUND_LINK = "ground link"
    MEMBER_LINK = "member link"


@dataclass(frozen=True)
class StreamCost:
    """One stream's cost per frame, measured: CPU ms on the ground host and on the member hosts (all
    member hosts together), bytes in and out of the ground host's link and of the member hosts' links (all
    together); ``source_cpu_ms``, the frames' source (the cameras: in a fleet on their own devices, counted
    only where every process shares one pool of cores); ``workers_per_frame``, how many workers share a
    frame's patches."""

    fps: float
    ground_cpu_ms: float
    member_cpu_ms: float
    ground_bytes: float
    member_bytes: float
    source_cpu_ms: float = 0.0
    master_cpu_ms: float = 0.0
    foreman_cpu_ms: float = 0.0
    worker_cpu_ms: float = 0.0
    workers_per_frame: int = 1

    def __post_init__(self) -> None:
        values = (
            self.fps, self.ground_cpu_ms, self.member_cpu_ms, self.ground_bytes, self.member_bytes,
            self.source_cpu_ms,
        )  # fmt: skip
        if not all(math.isfinite(v) and v >= 0.0 for v in values) or self.fps <= 0.0:
            raise InputError(f"need fps > 0 and finite costs >= 0, got {values}")
        if self.workers_per_frame < 1:
            raise InputError(f"need workers_per_frame >= 1, got {self.workers_per_frame}")


@dataclass(frozen=True)
class Fleet:
    """What the cluster runs on: ``hosts`` member hosts of ``cores_per_host`` cores, a ground host of
    ``ground_cores``, links of ``link_bit_s`` (None: not limited); or, with ``shared_cores``, one pool of
    cores every process shares (the hosts emulated on one machine)."""

    hosts: int
    cores_per_host: float
    ground_cores: float
    link_bit_s: float | None = None
    shared_cores: float | None = None
    max_utilisation: float = 0.8

    def __post_init__(self) -> None:
        if self.hosts < 1 or not self.cores_per_host > 0 or not self.ground_cores > 0:
            raise InputError(f"need hosts >= 1 and cores > 0, got {self.hosts}, {self.cores_per_host}")
        if self.link_bit_s is not None and not self.link_bit_s > 0:
            raise InputError(f"need a link rate > 0, got {self.link_bit_s}")
        if self.shared_cores is not None and not self.shared_cores > 0:
            raise InputError(f"need shared cores > 0, got {self.shared_cores}")
        if not 0.0 < self.max_utilisation <= 1.0:
            raise InputError(f"need 0 < max_utilisation <= 1, got {self.max_utilisation}")


@dataclass(frozen=True)
class Prediction:
    """Streams the fleet carries (``streams_exact``: the ceiling over the use per stream, not rounded down),
    the resource that limits them, each resource's use per stream (a share of its capacity) and the frame's
    critical path at low load (ms)."""

    streams: int
    streams_exact: float
    limited_by: Resource
    use_per_stream: dict[Resource, float]
    path_ms: float


def _use_per_stream(cost: StreamCost, fleet: Fleet) -> dict[Resource, float]:
    """Each resource's share of its capacity that one stream takes."""
    use: dict[Resource, float] = {}
    cpu_s = cost.fps / 1e3  # ms of CPU per frame -> cores
    if fleet.shared_cores is not None:
        total_ms = cost.ground_cpu_ms + cost.member_cpu_ms + cost.source_cpu_ms
        use[Resource.SHARED_CPU] = cpu_s * total_ms / fleet.shared_cores
    else:
        use[Resource.GROUND_CPU] = cpu_s * cost.ground_cpu_ms / fleet.ground_cores
        use[Resource.MEMBER_CPU] = cpu_s * cost.member_cpu_ms / (fleet.hosts * fleet.cores_per_host)
    if fleet.link_bit_s is not None:
        use[Resource.GROUND_LINK] = 8.0 * cost.fps * cost.ground_bytes / fleet.link_bit_s
        use[Resource.MEMBER_LINK] = 8.0 * cost.fps * cost.member_bytes / (fleet.hosts * fleet.link_bit_s)
    return use


def predict(cost: StreamCost, fleet: Fleet) -> Prediction:
    """The most streams every resource carries within ``max_utilisation``, and the latency at that load."""
    use = _use_per_stream(cost, fleet)
    limits = {r: fleet.max_utilisation / u for r, u in use.items() if u > 0.0}
    if not limits:
        raise InputError("a stream that costs no CPU and no bytes: nothing to predict from")
    limited_by = min(limits, key=lambda r: limits[r])
    exact = limits[limited_by]
    cores = fleet.cores_per_host if fleet.shared_cores is None else fleet.shared_cores
    parallel = max(1.0, min(float(cost.workers_per_frame), cores))
    path_ms = cost.master_cpu_ms + cost.foreman_cpu_ms + cost.worker_cpu_ms / parallel
    if fleet.link_bit_s is not None:
        path_ms += 1e3 * 8.0 * (cost.ground_bytes / 2.0) / fleet.link_bit_s  # one way: half of in + out
    return Prediction(math.floor(exact + 1e-9), exact, limited_by, use, path_ms)
