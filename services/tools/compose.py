"""A docker-compose document for a described cluster (``capataz up --compose FILE``).

Valid for Compose v1 (``docker-compose``) and v2 (``docker compose``): no top-level ``name`` (v1 refuses
it; the project name comes from the folder or ``-p``). Each service can build the image (``build:``, with the
host's network so that pip reaches PyPI on engines without a default bridge). The router's port is published
on 127.0.0.1 only unless another address is asked for. No ``init: true``: the image's entry point is tini
already (and the engine's docker-init could not be mounted on this project's machines).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from services.tools.cluster_file import ClusterSpec, cluster_commands

DEFAULT_IMAGE = "capataz:0.1.0"
#: the repository root (holds deploy/Dockerfile): the build context of a generated compose file
REPO_ROOT = Path(__file__).resolve().parents[2]
ROUTER_PORT = 7447


def build_section(compose_dir: Path) -> dict[str, Any]:
    """``build:`` for a compose file in ``compose_dir`` (context relative to it, as compose resolves it)."""
    context = os.path.relpath(REPO_ROOT, compose_dir.resolve())
    return {"context": context, "dockerfile": "deploy/Dockerfile", "network": "host"}


def compose_from_cluster(
    spec: ClusterSpec,
    image: str = DEFAULT_IMAGE,
    compose_dir: Path | None = None,
    publish_address: str = "127.0.0.1",
    camera_args: Sequence[str] = (),
) -> dict[str, Any]:
    """A docker-compose document for a described cluster (router, camera, master, foremen, workers);
    ``camera_args``: more camera options (``--frame-codec png``).

    A host's ``cpus`` list becomes the containers' ``cpuset`` (the compose twin of ``taskset``).
    ``compose_dir``: where the file will live (``build.context`` is relative to it; default: the repository).
    """
    build = build_section(compose_dir if compose_dir is not None else REPO_ROOT)
    env = {
        "CAPATAZ_ZENOH_MODE": "peer",
        "CAPATAZ_ZENOH_CONNECT": f"tcp/router:{ROUTER_PORT}",
        "CAPATAZ_ZENOH_LISTEN": "tcp/0.0.0.0:0",
        "CAPATAZ_ZENOH_MULTICAST": "false",
        "CAPATAZ_ZENOH_SHM": "false",
    }

    def base() -> dict[str, Any]:
        return {
            "image": image,
            "restart": "unless-stopped",
            "depends_on": ["router"],
            "environment": dict(env),
        }

    services: dict[str, Any] = {
        "router": {
            "image": image,
            "build": build,
            "restart": "unless-stopped",
            "command": ["router", "--listen", f"tcp/0.0.0.0:{ROUTER_PORT}", "--no-multicast", "--no-shm"],
            "ports": [f"{publish_address}:{ROUTER_PORT}:{ROUTER_PORT}"],
        },
        "camera": {
            **base(),
            "command": ["camera", "--node", "camera", "--uav", spec.uav, "--loop", *camera_args],
        },
    }
    # the processes as `capataz up` starts them (one rendering of a cluster file for both)
    for command in cluster_commands(spec):
        role, node, index = command.name.split("/")
        name = {"master": "master", "foreman": f"foreman-{node}"}.get(role, f"worker-{node}-{index}")
        services[name] = {**base(), "command": list(command.args)}
        if command.cpus:
            services[name]["cpuset"] = command.cpus
    return {"services": services}
