"""The compose deployment on a real Docker engine: build the image, bring up docker-compose.yml (the secure
profile: certificates made on first start by its ``certs`` service), read yaw, attitude, pose/vo and pose/pf
from a Zenoh client on the host holding the read-only ``client`` certificate the deployment exported to
out/secure/client, over mutual TLS, check them against the simulator's truth, stop.

Opt-in (``make test-docker``, which sets CAPATAZ_DOCKER_TEST=1): it builds the image (minutes). It skips with
the reason when no engine answers or no Compose is installed. Without Docker Hub, set BASE_IMAGE to a local
base image (deploy/make-base-image.sh builds one; ``capataz-base:bookworm`` is used when it exists). The
figures go to out/docker_e2e_v1.json / _v2.json (`capataz results` puts them in docs/results.md);
CAPATAZ_COMPOSE=v1|v2 picks the Compose.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh

from common.geometry import euler_from_quaternion
from common.sim.flight import hover_flight
from common.sim.scene import default_flight
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import AttitudeEstimate, PoseEstimate, YawEstimate
from common.wire.schema import WireModel
from services.runtime.transport import TransportSettings, open_session, zbytes
from services.tools.bench import bench_metadata
from services.tools.report import write_json

ROOT = Path(__file__).resolve().parents[2]
PROJECT = "capataz-e2e"
IMAGE = "capataz:0.1.0"
LOCAL_BASE = "capataz-base:bookworm"
#: streams read from the host: name -> (key, message type)
STREAMS: dict[str, tuple[str, type[WireModel]]] = {
    "yaw": (keys.yaw_key("uav0"), YawEstimate),
    "attitude": (keys.attitude_key("uav0"), AttitudeEstimate),
    "pose/vo": (keys.pose_vo_key("uav0"), PoseEstimate),
    "pose/pf": (keys.pose_pf_key("uav1"), PoseEstimate),
}
#: messages per stream measured after all four are flowing (about 30 s: yaw 10 Hz, pose/pf 10 Hz)
COLLECT = {"yaw": 300, "attitude": 3000, "pose/vo": 100, "pose/pf": 100}
COLLECT_S = 30.0

pytestmark = [
    pytest.mark.docker,
    pytest.mark.zenoh,
    pytest.mark.timeout(1800),
    pytest.mark.skipif(
        os.environ.get("CAPATAZ_DOCKER_TEST") != "1",
        reason="Docker end-to-end test: opt in with `make test-docker` (builds the image: several minutes)",
    ),
]


def host_port() -> int:
    """A port free on the host now, for the router's published port (docker binds it moments later)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _run(*command: str, env: dict[str, str] | None = None, timeout: float = 1200) -> str:
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, env=env, timeout=timeout)
    assert done.returncode == 0, f"{' '.join(command)}: {done.stdout[-1500:]}{done.stderr[-1500:]}"
    return done.stdout


def _compose() -> list[str]:
    """Compose v1 (``docker-compose``) or v2 (``docker compose``): CAPATAZ_COMPOSE=v1|v2 chooses, otherwise
    whichever is installed (v2 first)."""
    wanted = os.environ.get("CAPATAZ_COMPOSE", "").strip().lower()
    if wanted not in {"", "v1", "v2"}:
        pytest.fail(f"CAPATAZ_COMPOSE={wanted!r}: expected v1 or v2")
    has_v2 = subprocess.run(["docker", "compose", "version"], capture_output=True).returncode == 0
    if wanted in {"", "v2"} and has_v2:
        return ["docker", "compose"]
    if wanted in {"", "v1"} and shutil.which("docker-compose"):
        return ["docker-compose"]
    pytest.skip(f"no Docker Compose {wanted or ''} (docker-compose for v1, the docker compose plugin for v2)")


@pytest.fixture(scope="module")
def engine() -> None:
    if shutil.which("docker") is None:
        pytest.skip("no docker client installed")
    info = subprocess.run(["docker", "info"], capture_output=True, text=True, timeout=30)
    if info.returncode != 0:
        pytest.skip(f"no Docker engine answers (docker info: {info.stderr.strip().splitlines()[-1:]})")


class Streams:
    """Every message of the four streams, with its arrival time."""

    def __init__(self, session: zenoh.Session) -> None:
        self.samples: dict[str, list[tuple[float, WireModel]]] = {name: [] for name in STREAMS}
        self.lock = threading.Lock()
        self.subs = [
            session.declare_subscriber(key, self._handler(name, kind))
            for name, (key, kind) in STREAMS.items()
        ]

    def _handler(self, name: str, kind: type[WireModel]) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            message = decode(zbytes(sample.payload), zbytes(sample.attachment), kind)
            with self.lock:
                self.samples[name].append((time.monotonic(), message))

        return on_sample

    def collected(self, since: float) -> bool:
        """Each stream has :data:`COLLECT` messages that arrived after ``since``."""
        with self.lock:
            return all(sum(1 for t, _ in self.samples[n] if t >= since) >= k for n, k in COLLECT.items())

    def first_arrival(self, name: str) -> float | None:
        with self.lock:
            return self.samples[name][0][0] if self.samples[name] else None


def _accuracy(samples: dict[str, list[tuple[float, WireModel]]]) -> dict[str, float]:
    """Errors against the simulator's truth over the flights' first round (the cameras loop)."""
    hover, office = hover_flight(seed=0), default_flight(n_frames=2041)
    yaws = [m for _, m in samples["yaw"] if isinstance(m, YawEstimate) and m.seq < len(hover.frame_stamps_s)]
    truth_yaw = hover.euler_rad[:, 2]
    ref = yaws[0]
    yaw_err = [
        np.rad2deg((m.yaw_rad - ref.yaw_rad) - (truth_yaw[m.seq] - truth_yaw[ref.seq])) for m in yaws[1:]
    ]
    attitude = [
        m
        for _, m in samples["attitude"]
        if isinstance(m, AttitudeEstimate) and m.stamp_s <= hover.frame_stamps_s[-1]
    ]
    rp_err = [
        np.rad2deg(
            euler_from_quaternion(m.q_world_body)[:2]
            - np.array([np.interp(m.stamp_s, hover.frame_stamps_s, hover.euler_rad[:, k]) for k in (0, 1)])
        )
        for m in attitude
    ]
    pf = [
        m for _, m in samples["pose/pf"] if isinstance(m, PoseEstimate) and 75 <= m.seq < len(office.times_s)
    ]
    pf_err = [float(np.linalg.norm(m.p_world_body_m[:2] - office.states[m.seq, :2])) * 100 for m in pf]
    return {
        "yaw_max_error_deg": float(np.max(np.abs(yaw_err))) if yaw_err else float("nan"),
        "yaw_rms_error_deg": float(np.sqrt(np.mean(np.square(yaw_err)))) if yaw_err else float("nan"),
        "attitude_rp_rms_error_deg": float(np.sqrt(np.mean(np.square(rp_err)))) if rp_err else float("nan"),
        "pf_median_xy_error_cm": float(np.median(pf_err)) if pf_err else float("nan"),
    }


def test_compose_deployment_publishes_the_four_outputs(engine: None, tmp_path: Path) -> None:
    compose = _compose()
    base = os.environ.get("BASE_IMAGE")
    if (
        base is None
        and subprocess.run(["docker", "image", "inspect", LOCAL_BASE], capture_output=True).returncode == 0
    ):
        base = LOCAL_BASE
    build_args = ["--build-arg", f"BASE_IMAGE={base}"] if base else []
    t0 = time.monotonic()
    _run("docker", "build", "--network=host", *build_args, "-f", "deploy/Dockerfile", "-t", IMAGE, ".")
    build_s = time.monotonic() - t0
    size_mb = int(_run("docker", "image", "inspect", "-f", "{{.Size}}", IMAGE)) / 1e6

    port = host_port()
    # vfs (no overlay filesystem here) copies the whole image for each of the 12 containers: give compose time
    env = dict(os.environ, CAPATAZ_PORT=str(port), COMPOSE_PROJECT_NAME=PROJECT, COMPOSE_HTTP_TIMEOUT="900")
    if base:
        env["BASE_IMAGE"] = base
    down = [*compose, "-p", PROJECT, "down", "-v", "--timeout", "10"]  # -v: the certificates' volumes too
    t_up = time.monotonic()
    try:
        _run(*compose, "-p", PROJECT, "up", "-d", "--no-build", env=env, timeout=1200)
        created_s = time.monotonic() - t_up
        client = ROOT / "out" / "secure" / "client"  # what the deployment's certs service exported
        settings = TransportSettings(
            mode="client", connect=(f"tls/127.0.0.1:{port}",), connect_timeout_ms=60000,
            tls_ca=client / "ca.pem", tls_cert=client / "client.pem", tls_key=client / "client.key",
        )  # fmt: skip
        with open_session(settings) as session:
            streams = Streams(session)
            deadline = time.monotonic() + 600
            while time.monotonic() < deadline and not all(streams.first_arrival(n) for n in STREAMS):
                time.sleep(0.5)
            first = {n: streams.first_arrival(n) for n in STREAMS}
            missing = [n for n, t in first.items() if t is None]
            logs = "" if not missing else _run(*compose, "-p", PROJECT, "logs", "--tail", "20", env=env)
            assert not missing, f"no {missing} after 600 s; logs: {logs[-3000:]}"
            t_collect = time.monotonic()
            while time.monotonic() < t_collect + 3 * COLLECT_S and not streams.collected(t_collect):
                time.sleep(0.5)
            with streams.lock:
                samples = {n: list(v) for n, v in streams.samples.items()}
            for sub in streams.subs:
                sub.undeclare()
        # an operator's view of the deployment, with the same read-only certificate (issue 28)
        tls = {"CA": client / "ca.pem", "CERT": client / "client.pem", "KEY": client / "client.key"}
        status_env = dict(os.environ, **{f"CAPATAZ_ZENOH_TLS_{k}": str(v) for k, v in tls.items()})
        status = subprocess.run(
            [sys.executable, "-m", "services.tools.cli", "status", "--connect", f"tls/127.0.0.1:{port}",
             "--json"],
            capture_output=True, text=True, cwd=ROOT, env=status_env, timeout=300,
        )  # fmt: skip
        assert status.returncode == 0, status.stderr[-2000:]
        members = json.loads(status.stdout)["members"]
    finally:
        # every service's log, kept for a reader of a failure (out/ is ignored by git)
        all_logs = subprocess.run(
            [*compose, "-p", PROJECT, "logs", "--no-color"],
            capture_output=True, text=True, cwd=ROOT, env=env, timeout=300,
        )  # fmt: skip
        (ROOT / "out").mkdir(exist_ok=True)
        (ROOT / "out" / "docker_e2e_logs.txt").write_text(all_logs.stdout + all_logs.stderr)
        subprocess.run(down, capture_output=True, cwd=ROOT, env=env, timeout=300)

    rates = {
        n: sum(1 for t, _ in v if t >= t_collect) / (max(t for t, _ in v) - t_collect)
        for n, v in samples.items()
    }
    accuracy = _accuracy(samples)
    version = _run(*compose, "version", "--short").strip()
    figures = {
        "compose": f"{' '.join(compose)} {version}",
        "image_size_mb": size_mb,
        "build_s": build_s,
        "base_image": base or "python:3.11-slim-bookworm",
        "containers_created_s": created_s,
        "time_to_first_s": {n: t - t_up for n, t in first.items() if t is not None},
        "rates_hz": rates,
        "counts": {n: len(v) for n, v in samples.items()},
        "status_members": len(members),
        "status_not_ok": [m["member"] for m in members if m["state"] != "ok"],
        **accuracy,
        "metadata": bench_metadata(
            "docker", f"{'CAPATAZ_COMPOSE=v2 ' if compose[0] == 'docker' else ''}make test-docker"
        ),
    }
    write_json(ROOT / "out" / f"docker_e2e_{'v2' if compose[0] == 'docker' else 'v1'}.json", figures)
    print(json.dumps(figures, indent=2))
    assert (
        rates["yaw"] > 5.0 and rates["attitude"] > 100.0 and rates["pose/pf"] > 1.0 and rates["pose/vo"] > 1.0
    )
    # router, 2 cameras, master, 2 foremen, 4 workers, estimator, localizer: each listed with its health
    assert len(members) == 12 and all(m["health"] is not None for m in members), members
    assert accuracy["yaw_max_error_deg"] < 1.0
    assert accuracy["attitude_rp_rms_error_deg"] < 1.0
    assert accuracy["pf_median_xy_error_cm"] < 10.0
