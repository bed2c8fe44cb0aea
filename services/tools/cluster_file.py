"""The cluster file (``deploy/clusters/*.yml``): which hosts run which members, read by ``capataz up``, the
compose generator, the load test and the benchmarks.

A YAML mapping, every key checked (an unknown key is refused with the file's name)::

    name: 2h8n                      # paper A's notation: 2 hosts, 8 worker nodes
    description: two hosts ...      # free text (optional)
    topology: master-foreman-worker # or master-worker (the master addresses every worker itself)
    balance: time                   # time: shares follow each member's measured speed; none: equal shares
    speed: round_trip               # what "speed" means for time balancing: round_trip or reported
    master_computes: false          # the master computes a share as well as dispatching
    job_encoding: mono8             # how a share's pixels travel to the members: mono8, zstd or jpeg
    job_quality: 90                 # JPEG quality of a share with job_encoding jpeg (1-100)
    min_deadline_ms: 300            # the dispatchers' smallest member deadline (optional; their default)
    master_cpus: "0"                # taskset CPU list of the master (optional)
    aux_cpus: "0"                   # taskset CPU list of the router and the camera (optional)
    uav: uav0                       # the UAV stream the master serves
    hosts:                          # one entry per host: a foreman and its workers
      - name: h1                    # node name (letters, digits, _ . -)
        workers: 4                  # workers on this host (>= 0)
        cpus: "1"                   # taskset CPU list of its processes (optional): a slow host made real
        foreman_computes: false     # the foreman computes a share too
        cpu_factor: 1               # emulated slowdown of its workers (>= 1)

:func:`cluster_commands` renders a :class:`ClusterSpec` as ``capataz`` command lines, the one rendering that
``capataz up`` and the compose generator share.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common.dispatch import Balance, DispatchSettings, SpeedSource
from common.errors import CapatazError
from common.members import Topology
from common.wire.jobs import JobEncoding
from common.wire.schema import MAX_BUDGET_S
from services.master.settings import MasterSettings
from services.runtime.usage import condense_validation_error, number_in, one_line


class ClusterError(CapatazError):
    """A cluster file is invalid or a cluster did not come up."""


class HostSpec(BaseModel):
    """One host: a foreman and its workers, optionally pinned to CPUs."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    workers: int = Field(ge=0)
    #: taskset CPU list for the host's processes, e.g. "1" or "0-1"; None = no pinning
    cpus: str | None = None
    #: the foreman computes a share too
    foreman_computes: bool = False
    #: emulated CPU slowdown of the host's workers (``capataz worker --cpu-factor``)
    cpu_factor: int = Field(default=1, ge=1)


_JOB_QUALITY = MasterSettings.model_fields["job_quality"]


class ClusterSpec(BaseModel):
    """A cluster description (``deploy/clusters/*.yml``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    description: str = ""
    topology: Topology = Topology.MASTER_FOREMAN_WORKER
    balance: Balance = Balance.TIME
    #: speed measure of time balancing (master and foremen): members' own figures or round-trip rates
    speed: SpeedSource = SpeedSource.ROUND_TRIP
    master_computes: bool = False
    #: the master's ``--job-encoding`` (zstd: members across a thin link)
    job_encoding: JobEncoding = MasterSettings.model_fields["job_encoding"].default
    #: the master's ``--job-quality`` (JPEG's, with ``job_encoding: jpeg``): its field, bounds included
    job_quality: Annotated[int, _JOB_QUALITY] = _JOB_QUALITY.default
    #: the master's and the foremen's ``--min-deadline-ms`` (a member's smallest deadline before its share
    #: is computed elsewhere and it is paused); None = their default. A load test or bench on a busy host
    #: raises it to measure the balanced path rather than the fault path
    min_deadline_ms: float | None = Field(default=None, gt=0.0, le=1e3 * MAX_BUDGET_S)
    master_cpus: str | None = None
    #: taskset CPU list of the router and the camera
    aux_cpus: str | None = None
    uav: str = "uav0"
    hosts: tuple[HostSpec, ...]

    @property
    def n_workers(self) -> int:
        return sum(h.workers for h in self.hosts)


@dataclass(frozen=True)
class ServiceCommand:
    """One cluster process as ``capataz`` arguments, without transport options (added by where it runs:
    :class:`LocalCluster` adds endpoints, compose sets ``CAPATAZ_ZENOH_*``)."""

    #: ``role/node/index``, the name of its liveliness token
    name: str
    args: tuple[str, ...]
    #: taskset CPU list (compose: cpuset); None = not pinned
    cpus: str | None = None


def deadline_args(spec: ClusterSpec) -> list[str]:
    """The dispatchers' ``--min-deadline-ms`` when the cluster sets one."""
    return [] if spec.min_deadline_ms is None else ["--min-deadline-ms", f"{spec.min_deadline_ms:g}"]


def add_deadline_argument(parser: argparse.ArgumentParser) -> None:
    """``--min-deadline-ms`` of a tool that starts a cluster (its :attr:`ClusterSpec.min_deadline_ms`)."""
    parser.add_argument(
        "--min-deadline-ms", type=number_in(float, 1.0, 1e3 * MAX_BUDGET_S),
        help="the master's and foremen's smallest per-member deadline (default: theirs, "
        f"{1e3 * DispatchSettings().min_deadline_s:g} ms); on a busy host a larger one keeps a late member's "
        "share from moving to the master, which the run would then measure instead of the balanced path",
    )  # fmt: skip


def with_deadline(spec: ClusterSpec, min_deadline_ms: float | None) -> ClusterSpec:
    """``spec`` with the dispatchers' ``--min-deadline-ms`` (None: as it is)."""
    return spec if min_deadline_ms is None else spec.model_copy(update={"min_deadline_ms": min_deadline_ms})


def worker_command(spec: ClusterSpec, host: HostSpec, index: int) -> ServiceCommand:
    args = ["worker", "--node", host.name, "--index", str(index)]
    if host.cpu_factor != 1:
        args += ["--cpu-factor", str(host.cpu_factor)]
    return ServiceCommand(f"worker/{host.name}/{index}", tuple(args), host.cpus)


def foreman_command(spec: ClusterSpec, host: HostSpec) -> ServiceCommand:
    compute = "--compute" if host.foreman_computes else "--no-compute"
    args = ("foreman", "--node", host.name, "--balance", spec.balance.value, compute,
            "--speed", spec.speed.value, *deadline_args(spec))  # fmt: skip
    return ServiceCommand(f"foreman/{host.name}/0", args, host.cpus)


def master_command(spec: ClusterSpec, node: str = "master", uav: str | None = None) -> ServiceCommand:
    """The master of ``uav`` (default: the file's) on ``node`` (the load test runs one per UAV, standbys
    too: every master takes the file's options, ``job_encoding``, ``job_quality`` and ``min_deadline_ms``
    included)."""
    args = ["master", "--node", node, "--uav", uav or spec.uav, "--topology", spec.topology.value,
            "--balance", spec.balance.value, "--compute" if spec.master_computes else "--no-compute",
            "--speed", spec.speed.value, *deadline_args(spec)]  # fmt: skip
    if spec.job_encoding != MasterSettings.model_fields["job_encoding"].default:
        args += ["--job-encoding", spec.job_encoding]
    if spec.job_quality != _JOB_QUALITY.default:
        args += ["--job-quality", str(spec.job_quality)]
    return ServiceCommand(f"master/{node}/0", tuple(args), spec.master_cpus)


def cluster_commands(spec: ClusterSpec) -> list[ServiceCommand]:
    """Every process of the cluster but the router and the camera, in start order (workers, foremen,
    master): the one rendering of a :class:`ClusterSpec` for ``capataz up`` and for compose."""
    commands: list[ServiceCommand] = []
    for host in spec.hosts:
        commands += [worker_command(spec, host, i) for i in range(host.workers)]
        if spec.topology is Topology.MASTER_FOREMAN_WORKER:
            commands.append(foreman_command(spec, host))
    return [*commands, master_command(spec)]


def load_cluster(path: Path) -> ClusterSpec:
    try:
        raw = yaml.safe_load(Path(path).read_text())
        return ClusterSpec.model_validate(raw)
    except ValidationError as exc:
        raise ClusterError(f"{path}: {condense_validation_error(exc)}") from None
    except (OSError, yaml.YAMLError) as exc:
        raise ClusterError(f"{path}: {one_line(str(exc))}") from None
