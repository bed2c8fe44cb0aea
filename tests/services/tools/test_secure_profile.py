"""The secure profile's files: the least-privilege table, the committed Zenoh config, the certificate script
and the default (secure) docker-compose.yml."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from common.wire import keys
from services.runtime.acl import PolicySettings, acl_section, markdown_table, role_table
from services.tools.cli import build_parser
from services.tools.secure import DEPLOY_CONFIG, SecureProfile, make_certs, profile_of, render_config
from tests.builders import small_cluster_file
from tests.services.tools.test_deploy import check_compose

ROOT = Path(__file__).resolve().parents[3]


def allowed(common_name: str, flow: str, message: str) -> set[str]:
    """Key expressions ``common_name`` is allowed for ``message`` in ``flow``."""
    section = acl_section()
    rules = {r["id"]: r for r in section["rules"]}
    out: set[str] = set()
    for policy in section["policies"]:
        if common_name not in policy["subjects"]:
            continue
        for rid in policy["rules"]:
            rule = rules[rid]
            if flow in rule["flows"] and message in rule["messages"]:
                out |= set(rule["key_exprs"])
    return out


def who_may(flow: str, message: str, key: str) -> set[str]:
    names = {r.common_name for r in role_table()} - {"router"}
    return {n for n in names if key in allowed(n, flow, message)}


def test_least_privilege_table_of_the_issue() -> None:
    assert who_may("ingress", "put", keys.camera_key("uav0")) == {"camera.uav0"}
    assert who_may("ingress", "put", keys.imu_key("uav1")) == {"camera.uav1"}
    assert who_may("ingress", "put", keys.yaw_key("uav0")) == {"master.uav0"}
    assert who_may("ingress", "put", keys.attitude_key("uav0")) == {"estimator.uav0"}
    assert who_may("ingress", "put", keys.pose_vo_key("uav0")) == {"estimator.uav0"}
    # the office flight has no estimator: its camera's simulated odometry is the one exception
    assert who_may("ingress", "put", keys.pose_vo_key("uav1")) == {"estimator.uav1", "camera.uav1"}
    assert who_may("ingress", "put", keys.pose_pf_key("uav1")) == {"localizer.uav1"}
    # identity per node (issue 27): a foreman serves only its node's block key and queries only its node's
    # workers; a worker serves only its node's keys; tokens, stats and health only under its node
    for node in ("h1", "h2", "h3"):
        assert who_may("ingress", "declare_queryable", keys.foreman_key(node)) == {f"foreman.{node}"}
        assert who_may("ingress", "declare_queryable", f"capataz/node/{node}/worker/*") == {f"worker.{node}"}
        assert who_may("ingress", "query", f"capataz/node/{node}/worker/*") == {f"foreman.{node}"}
        for role in ("foreman", "worker"):
            token = f"capataz/alive/{role}/{node}/**"
            assert who_may("ingress", "liveliness_token", token) == {f"{role}.{node}"}
    assert "foreman" not in {r.common_name for r in role_table()}  # no certificate valid on every node
    queriers = {
        n
        for n in {r.common_name for r in role_table()}
        if "capataz/node/*/foreman" in allowed(n, "ingress", "query")
    }
    assert queriers == {"master.uav0", "master.uav1"}
    client = {
        m: allowed("client", "ingress", m) for m in ("put", "declare_queryable", "liveliness_token", "reply")
    }
    assert client == {"put": set(), "declare_queryable": set(), "liveliness_token": set(), "reply": set()}
    assert allowed("client", "ingress", "declare_subscriber") >= {
        "capataz/uav/*/yaw",
        "capataz/uav/*/pose/pf",
    }
    assert "capataz/uav/*/camera" not in allowed("client", "egress", "put")  # no raw frames to clients
    assert acl_section()["default_permission"] == "deny"


def test_the_committed_secure_config_is_the_generated_one() -> None:
    assert DEPLOY_CONFIG.read_text() == render_config(), (
        "run: capataz secure config --out deploy/zenoh/secure.json5"
    )
    body = "\n".join(line for line in DEPLOY_CONFIG.read_text().splitlines() if not line.startswith("//"))
    assert json.loads(body)["transport"]["link"]["protocols"] == ["tls"]


def test_the_security_page_has_the_generated_role_table() -> None:
    assert markdown_table() in (ROOT / "docs" / "security.md").read_text()


def test_policy_refuses_bad_uav_names() -> None:
    with pytest.raises(Exception, match="uav"):
        PolicySettings(uavs=("uav/0",))


def subject(path: Path) -> str:
    return subprocess.run(
        ["openssl", "x509", "-in", str(path), "-noout", "-subject"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def test_make_certs_gives_each_role_its_common_name_and_private_keys(certs: Path) -> None:
    for name in (
        "router",
        "worker.h1",
        "foreman.h2",
        "client",
        "camera.uav0",
        "master.uav0",
        "localizer.uav0",
    ):
        assert re.search(rf"CN\s*=\s*{re.escape(name)}$", subject(certs / f"{name}.pem").strip()), name
        assert (certs / f"{name}.key").stat().st_mode & 0o077 == 0, f"{name}.key is readable by others"


def test_the_ca_key_lives_apart_from_the_role_keys_and_every_folder_is_private(tmp_path: Path) -> None:
    """Regression (issue 27): ca.key was written among the role keys, in a folder whose mode followed the
    umask (0755 seen)."""
    out = tmp_path / "secure" / "certs"
    old = os.umask(0o022)
    try:
        make_certs(out, ("uav0",))
    finally:
        os.umask(old)
    ca_dir = tmp_path / "secure" / "certs-ca"
    assert not (out / "ca.key").exists() and (ca_dir / "ca.key").is_file()
    assert {p.suffix for p in out.iterdir()} == {".pem", ".key"}  # no serial or CSR left behind
    for folder in (out, ca_dir):
        assert folder.stat().st_mode & 0o777 == 0o700, folder
    for key in [*out.glob("*.key"), ca_dir / "ca.key"]:
        assert key.stat().st_mode & 0o777 == 0o600, key


def test_running_make_certs_again_rotates_role_certificates_under_the_same_ca(
    certs: Path, tmp_path: Path
) -> None:
    copy = tmp_path / "c"
    shutil.copytree(certs, copy)
    shutil.copytree(certs.parent / f"{certs.name}-ca", tmp_path / "c-ca")  # the CA key, beside them
    before_ca, before_worker = (copy / "ca.pem").read_bytes(), (copy / "worker.h1.pem").read_bytes()
    make_certs(copy, ("uav0",))
    assert (copy / "ca.pem").read_bytes() == before_ca
    assert (copy / "worker.h1.pem").read_bytes() != before_worker
    check = subprocess.run(
        ["openssl", "verify", "-CAfile", str(copy / "ca.pem"), str(copy / "worker.h1.pem")],
        capture_output=True,
    )
    assert check.returncode == 0


def test_secure_profile_environment_names_a_certificate_of_the_role(certs: Path, tmp_path: Path) -> None:
    shutil.copytree(certs, tmp_path / "p" / "certs")
    profile = SecureProfile.ensure(tmp_path / "p", ("uav0",))
    env = profile.environment("master.uav0")
    assert (
        env["CAPATAZ_ZENOH_TLS_CERT"].endswith("master.uav0.pem")
        and Path(env["CAPATAZ_ZENOH_CONFIG"]).is_file()
    )
    with pytest.raises(Exception, match="no certificate"):
        profile.environment("intruder")


def test_the_default_compose_file_is_secure_and_each_service_mounts_only_its_own_certificate() -> None:
    """Issue 27: docker-compose.yml is the secure profile. Certificates are made on first start by the
    one-shot ``certs`` service into the ``capataz-secure`` volume (the CA key never leaves it); each service
    mounts, read-only, a volume of its own with ca.pem and its own certificate and key."""
    document = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    check_compose(document)
    open_services = yaml.safe_load((ROOT / "docker-compose.open.yml").read_text())["services"]
    services = {n: s for n, s in document["services"].items() if n != "certs"}
    assert set(services) == set(open_services)
    assert services["router"]["ports"] == ["127.0.0.1:${CAPATAZ_PORT:-7447}:7447"]
    certs = document["services"]["certs"]
    made = {v.split(":")[0]: v.split(":")[1] for v in certs["volumes"]}
    assert made["capataz-secure"] == "/secure"  # the CA key's only home
    script = certs["command"][0]
    assert "make-certs.sh /secure/certs" in script  # the CA key goes to /secure/certs-ca, in that volume
    for name, service in services.items():
        assert service["command"] == open_services[name]["command"] or name == "router", name
        assert service["depends_on"]["certs"] == {"condition": "service_completed_successfully"}, name
        env = service["environment"]
        assert env["CAPATAZ_ZENOH_CONFIG"] == "/etc/capataz/zenoh.json5"
        assert name == "router" or env["CAPATAZ_ZENOH_CONNECT"] == "tls/router:7447"
        assert all(v.endswith(":ro") for v in service["volumes"]), name
        volumes = [v.split(":")[0] for v in service["volumes"] if v.split(":")[1] == "/run/capataz"]
        assert len(volumes) == 1 and volumes[0].startswith("cert-"), name
        assert "capataz-secure" not in " ".join(service["volumes"]), name
        role = made[volumes[0]].removeprefix("/vol/")
        assert 'cp "/secure/certs/$$cn.key" "$$dir/key.pem"' in script and role in script, name
        # the metrics exporter is a read-only client: it subscribes to stats and queries health only
        assert name.startswith(role.split(".")[0]) or (name, role) == ("metrics", "client"), name
        if role.startswith(("foreman.", "worker.")):  # bound to its node
            assert f"--node {role.split('.')[1]}" in " ".join(service["command"]), name
        elif "." in role:
            assert f"--uav {role.split('.')[1]}" in " ".join(service["command"]), name


def test_up_takes_secure_and_zenoh_config_options() -> None:
    args = build_parser().parse_args(["up", "--cluster", "deploy/clusters/local2x2.yml"])
    assert args.secure == Path("out/secure") and not args.open and args.zenoh_config is None  # the default
    args = build_parser().parse_args(["up", "--cluster", "x.yml", "--open", "--zenoh-config", "z.json5"])
    assert args.zenoh_config == Path("z.json5") and args.open
    args = build_parser().parse_args(["loadtest", "--zenoh-config", "z.json5"])
    assert args.zenoh_config == Path("z.json5") and args.secure is None  # a harness on loopback: open
    with pytest.raises(SystemExit):
        build_parser().parse_args(["up", "--cluster", "x.yml", "--open", "--secure", "d"])
    for command in (["up", "--cluster", "x.yml"], ["loadtest"]):
        args = build_parser().parse_args([*command, "--secure", "certs-here", "--zenoh-config", "z.json5"])
        assert args.secure == Path("certs-here") and args.zenoh_config == Path("z.json5")


def test_only_a_uavs_masters_hold_its_election_tokens_and_clients_may_watch_them() -> None:
    elect = keys.election_all("uav0")
    assert who_may("ingress", "liveliness_token", elect) == {"master.uav0"}
    assert "capataz/elect/**" in allowed("client", "ingress", "declare_liveliness_subscriber")
    # a standby continues from the active master's yaw and learns its session from its health reply
    assert keys.yaw_key("uav0") in allowed("master.uav0", "ingress", "declare_subscriber")
    assert "capataz/health/master/**" in allowed("master.uav0", "ingress", "query")


def test_wildcard_declarations_reach_the_roles_whose_keys_they_intersect_but_no_data_is_widened() -> None:
    """Zenoh matches a declaration by inclusion: a client's ``capataz/uav/*/yaw`` subscription must be let
    through to the master that puts ``capataz/uav/uav0/yaw``, or the client gets nothing."""
    assert "capataz/uav/*/yaw" in allowed("master.uav0", "egress", "declare_subscriber")
    assert "capataz/uav/*/camera" not in allowed("master.uav0", "egress", "declare_subscriber")
    assert "capataz/health/**" in allowed("worker.h1", "egress", "query")
    # what a role may send is unchanged: no put, no queryable for a client, no yaw put for a camera
    assert allowed("client", "ingress", "put") == set()
    assert keys.yaw_key("uav0") not in allowed("camera.uav0", "ingress", "put")


SMALL_CLUSTER = small_cluster_file(hosts=1)


@pytest.mark.zenoh
def test_capataz_up_runs_the_secure_profile_by_default_and_open_only_when_asked(tmp_path: Path) -> None:
    """Issue 27: ``capataz up`` without a profile option is the secure profile (certificates made on first
    start, the CA key apart); its own read-only client receives the yaw over TLS."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (needed to make the development certificates)")
    spec = tmp_path / "small.yml"
    spec.write_text(SMALL_CLUSTER)
    command = ["up", "--cluster", str(spec), "--port", "0", "--frames", "5", "--fps", "0",
               "--in-flight", "1", "--logs", str(tmp_path / "logs")]  # fmt: skip
    done = subprocess.run(
        [sys.executable, "-m", "services.tools.cli", *command],
        capture_output=True, text=True, timeout=240, cwd=tmp_path, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert re.search(r"router tls/127\.0\.0\.1:\d+", done.stdout), done.stdout
    assert "received 5 yaw estimates" in done.stdout, done.stdout[-1000:]
    assert "open profile" not in done.stderr
    certs = tmp_path / "out" / "secure" / "certs"
    assert (certs / "master.uav0.pem").is_file() and not (certs / "ca.key").exists()
    assert (tmp_path / "out" / "secure" / "certs-ca" / "ca.key").is_file()
    parsed = build_parser().parse_args([*command, "--open"])
    assert parsed.open and profile_of(parsed, ("uav0",)) is None  # the lab profile: warned, not secure
