"""Deployment files: every compose file parses and uses only CLI commands and options that exist; the
image is non-root with a real init; each described cluster comes up locally with `capataz up`."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from services.tools.cli import build_parser
from services.tools.cluster_file import load_cluster
from services.tools.compose import compose_from_cluster
from services.tools.up import LocalCluster

ROOT = Path(__file__).resolve().parents[3]
CLUSTER_DIR = ROOT / "deploy" / "clusters"
CLUSTERS = sorted(CLUSTER_DIR.glob("*.yml"))


def registered_commands() -> set[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return set(sub.choices)  # type: ignore[arg-type]


def check_compose(document: dict) -> None:
    """Every service's command parses with the real CLI."""
    assert isinstance(document.get("services"), dict) and document["services"]
    commands = registered_commands()
    for name, service in document["services"].items():
        assert service.get("image") or service.get("build"), f"{name}: no image"
        assert not service.get("init"), f"{name}: the image's tini is PID 1 (init: true nests a second init)"
        if name == "certs":  # the secure file's one-shot shell step that makes the certificates
            assert service["entrypoint"] == ["/bin/sh", "-ec"] and set(service["environment"]) == {
                "CAPATAZ_UID"
            }
            continue
        command = service["command"]
        assert isinstance(command, list) and all(isinstance(c, str) for c in command), name
        assert command[0] in commands, f"{name}: unknown command {command[0]!r}"
        try:
            args = build_parser().parse_args(command)
        except SystemExit as exc:
            raise AssertionError(f"{name}: `capataz {' '.join(command)}` does not parse") from exc
        assert callable(args.handler)
        for key in service.get("environment", {}):
            assert key.startswith("CAPATAZ_ZENOH_"), f"{name}: unexpected environment {key}"


@pytest.mark.parametrize(
    ("name", "scheme"), [("docker-compose.yml", "tls"), ("docker-compose.open.yml", "tcp")]
)
def test_docker_compose_parses_and_every_command_exists(name: str, scheme: str) -> None:
    document = yaml.safe_load((ROOT / name).read_text())
    check_compose(document)
    services = document["services"]
    assert {"router", "camera", "master", "foreman-h1", "foreman-h2", "estimator", "localizer"} <= set(
        services
    )
    assert sum(1 for s in services if s.startswith("worker-")) == 4
    # the metrics exporter is opt-in: a profile, started only with --profile metrics
    assert services["metrics"]["profiles"] == ["metrics"]
    assert [s for s, v in services.items() if v.get("profiles")] == ["metrics"]
    environment = services["master"]["environment"]
    assert environment["CAPATAZ_ZENOH_CONNECT"] == f"{scheme}/router:7447"
    assert environment["CAPATAZ_ZENOH_MULTICAST"] == "false"


@pytest.mark.parametrize("path", CLUSTERS, ids=[p.stem for p in CLUSTERS])
def test_every_cluster_file_and_its_compose_form_are_valid(path: Path) -> None:
    spec = load_cluster(path)
    assert spec.hosts and spec.n_workers >= 1
    document = compose_from_cluster(spec)
    reparsed = yaml.safe_load(yaml.safe_dump(document))
    check_compose(reparsed)
    workers = [s for s in reparsed["services"] if s.startswith("worker-")]
    assert len(workers) == spec.n_workers
    for host in spec.hosts:
        if host.cpus:
            assert reparsed["services"][f"worker-{host.name}-0"]["cpuset"] == host.cpus


@pytest.mark.parametrize("path", CLUSTERS, ids=[p.stem for p in CLUSTERS])
def test_capataz_up_and_compose_start_the_same_processes_with_the_same_options(
    path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One rendering of a cluster file for both (compose used to drop ``--speed``)."""
    spec = load_cluster(path)
    cluster = LocalCluster(spec, tmp_path, port=7447)
    spawned: dict[str, tuple[tuple[str, ...], str | None]] = {}

    def spawn(name: str, args: list[str], cpus: str | None = None) -> None:
        transport = cluster.transport_args()
        assert args[-len(transport) :] == transport, name  # up adds only its endpoints to the command
        spawned[name] = (tuple(args[: -len(transport)]), cpus)

    monkeypatch.setattr(cluster, "spawn", spawn)
    monkeypatch.setattr(cluster, "start_router", lambda: None)
    cluster.start()
    composed = {}
    for service in compose_from_cluster(spec)["services"].values():
        command = service["command"]
        if command[0] in {"master", "foreman", "worker"}:
            args = build_parser().parse_args(command)
            composed[f"{command[0]}/{args.node}/{args.index}"] = (tuple(command), service.get("cpuset"))
    assert composed == spawned
    assert all("--speed" in args for name, (args, _cpus) in composed.items() if not name.startswith("worker"))


def test_paper_clusters_are_described() -> None:
    names = {p.stem for p in CLUSTERS}
    assert {"2h8n", "3h24n"} <= names
    for name, hosts, workers in (("2h8n", 2, 8), ("3h24n", 3, 24)):
        spec = load_cluster(ROOT / "deploy" / "clusters" / f"{name}.yml")
        assert (len(spec.hosts), spec.n_workers) == (hosts, workers)


def test_image_is_non_root_with_init_and_zenoh_is_pinned() -> None:
    dockerfile = (ROOT / "deploy" / "Dockerfile").read_text()
    assert re.search(r"^USER capataz$", dockerfile, re.M)
    assert 'ENTRYPOINT ["/usr/bin/tini", "--", "capataz"]' in dockerfile
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'"eclipse-zenoh==\d+\.\d+\.\d+"', pyproject), "zenoh must be pinned exactly"


@pytest.mark.zenoh
@pytest.mark.slow
@pytest.mark.parametrize(
    "path",
    [pytest.param(CLUSTER_DIR / "2h8n.yml"), pytest.param(CLUSTER_DIR / "3h24n.yml", marks=pytest.mark.long)],
    ids=lambda p: p.stem,
)
def test_capataz_up_brings_each_described_cluster_up(path: Path, tmp_path: Path) -> None:
    spec = load_cluster(path)
    command = [sys.executable, "-m", "services.tools.cli", "up", "--cluster", str(path), "--port", "0",
               "--frames", "10", "--fps", "0", "--in-flight", "1", "--logs", str(tmp_path),
               "--secure", str(tmp_path / "secure")]  # fmt: skip
    # the default profile: secure (certificates made on first start into --secure's folder)
    # flow control (one frame without a yaw at a time) instead of a frame rate: the count below does not
    # depend on how fast a loaded host is (at 10 fps a busy host dropped 3 of 10 frames)
    done = subprocess.run(command, capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert f"cluster {spec.name} up" in done.stdout
    received = int(re.search(r"received (\d+) yaw estimates", done.stdout).group(1))  # type: ignore[union-attr]
    assert received == 10, done.stdout[-1000:]
    logs = {p.name for p in tmp_path.glob("*.log")}
    assert len([n for n in logs if n.startswith("worker_")]) == spec.n_workers


@pytest.mark.parametrize("name", ["router", "peer"])
def test_zenoh_config_files_load_and_match_the_transport_settings(name: str) -> None:
    import zenoh

    from services.runtime.transport import TransportSettings

    config = zenoh.Config.from_file(str(ROOT / "deploy" / "zenoh" / f"{name}.json5"))
    assert config.get_json("mode") == f'"{name}"'
    defaults = TransportSettings()
    assert (
        config.get_json("scouting/multicast/enabled") == "false" == str(defaults.multicast_scouting).lower()
    )
    assert config.get_json("transport/shared_memory/enabled") == "false"
    assert int(config.get_json("transport/link/tx/lease")) == defaults.lease_ms
    assert int(config.get_json("transport/link/tx/queue/size/data")) == defaults.tx_queue_batches
    # issue 27: the deploy configs listen on loopback or TLS only, and link over TLS only
    endpoints = json.loads(config.get_json("listen/endpoints")) + json.loads(
        config.get_json("connect/endpoints")
    )
    assert endpoints and all(e.startswith("tls/") or e.startswith("tcp/127.") for e in endpoints), endpoints
    assert json.loads(config.get_json("transport/link/protocols")) == ["tls"]
    assert config.get_json("transport/link/tls/enable_mtls") == "true"


COMPOSE_V1 = shutil.which("docker-compose")


def _compose_v2() -> list[str] | None:
    """``docker compose`` (the v2 CLI plugin) when installed: it validates files without an engine."""
    if shutil.which("docker") is None:
        return None
    done = subprocess.run(["docker", "compose", "version"], capture_output=True, text=True, timeout=60)
    # "Docker Compose version v2.29.1" (Docker's build) or "Docker Compose version 2.26.1-4" (Debian's)
    is_v2 = done.returncode == 0 and re.search(r"version v?2\.", done.stdout) is not None
    return ["docker", "compose"] if is_v2 else None


COMPOSE_V2 = _compose_v2()


def compose_files(tmp_path: Path) -> list[Path]:
    """docker-compose.yml (secure), docker-compose.open.yml and what `capataz up --compose` writes for every
    described cluster."""
    from services.tools.up_command import write_compose

    generated = [
        write_compose(load_cluster(p), tmp_path / "compose" / f"{p.stem}.yml", "127.0.0.1") for p in CLUSTERS
    ]
    return [ROOT / "docker-compose.yml", ROOT / "docker-compose.open.yml", *generated]


def test_compose_files_build_the_image_and_publish_on_loopback_only(tmp_path: Path) -> None:
    for path in compose_files(tmp_path):
        document = yaml.safe_load(path.read_text())
        assert "name" not in document and "version" not in document, f"{path}: Compose v1 refuses 'name'"
        router = document["services"]["router"]
        assert router["build"]["dockerfile"] == "deploy/Dockerfile", path
        assert (path.parent / router["build"]["context"] / "deploy" / "Dockerfile").is_file(), path
        for name, service in document["services"].items():
            for port in service.get("ports", []):
                assert str(port).startswith(("127.0.0.1:", "${CAPATAZ_PUBLISH:-127.0.0.1}:")), (
                    f"{path} {name}"
                )


def _assert_valid(command: list[str], paths: list[Path]) -> None:
    for path in paths:
        done = subprocess.run([*command, "-f", str(path), "config", "-q"], capture_output=True, text=True,
                              timeout=60)  # fmt: skip
        assert done.returncode == 0, f"{' '.join(command)} {path}: {done.stderr}"


@pytest.mark.skipif(COMPOSE_V1 is None, reason="docker-compose (Compose v1) is not installed")
def test_compose_files_are_valid_for_compose_v1(tmp_path: Path) -> None:
    assert COMPOSE_V1 is not None
    _assert_valid([COMPOSE_V1], compose_files(tmp_path))


@pytest.mark.skipif(
    COMPOSE_V2 is None, reason="the docker compose v2 plugin is not installed (deploy/install-compose-v2.sh)"
)
def test_compose_files_are_valid_for_compose_v2(tmp_path: Path) -> None:
    assert COMPOSE_V2 is not None
    _assert_valid(COMPOSE_V2, compose_files(tmp_path))
