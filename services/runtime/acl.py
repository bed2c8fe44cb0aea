"""The least-privilege policy of capataz, per role, as a Zenoh 1.x ``access_control`` section.

A participant is identified by the common name (CN) of its TLS certificate (mutual TLS): ``router``,
``client``, bound to one node, ``foreman.{node}`` and ``worker.{node}`` (a foreman serves only its node's
block key and queries only its node's workers; a worker serves only its node's keys), and, bound to one
UAV, ``camera.{uav}``, ``master.{uav}``, ``estimator.{uav}``, ``localizer.{uav}``. :func:`role_table` says
what each may do; :func:`acl_section` turns it into ``rules`` / ``subjects`` / ``policies`` with
``default_permission: deny``:

- ingress from a subject: what it may *send* (puts, subscriptions, queryables and their replies, queries,
  liveliness tokens and liveliness watches);
- egress to a subject: what it may *receive* (puts on keys it may subscribe to, queries on keys it may
  serve, replies to keys it may query, tokens it may watch) and the declarations it needs to send.

The same section goes into every participant's configuration (router and peers), since the data path is
peer-to-peer: a peer that accepts a direct link from a foreign CN applies the same table. The router
(CN ``router``) forwards for everybody, so peers accept from it whatever any role may send: the router
enforces the table on each participant's ingress. Its key is therefore the one to guard most.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from common.members import Role, check_name
from common.wire import keys

ROOT = keys.ROOT
#: message kinds of Zenoh 1.10's access control (all of them, for the router subject)
ALL_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
)
FOREMAN_WORK = f"{ROOT}/node/*/foreman"
WORKER_WORK = f"{ROOT}/node/*/worker/*"
#: what a read-only client may see: the outputs of every UAV, stats, health and membership
OUTPUTS = ("yaw", "attitude", "pose/vo", "pose/pf")
DEFAULT_UAVS = ("uav0", "uav1")
#: the nodes of the described clusters (deploy/clusters/*.yml, docker-compose.yml)
DEFAULT_NODES = ("h1", "h2", "h3")
#: roles whose certificate is bound to one UAV (CN ``role.uav``), to one node (CN ``role.node``), and the
#: names bound to neither
UAV_ROLES = (Role.CAMERA, Role.MASTER, Role.ESTIMATOR, Role.LOCALIZER)
NODE_ROLES = (Role.FOREMAN, Role.WORKER)
GLOBAL_NAMES = ("router", "client")


@dataclass(frozen=True)
class RolePermissions:
    """What one certificate common name may do (key expressions, Zenoh syntax)."""

    common_name: str
    put: tuple[str, ...] = ()
    subscribe: tuple[str, ...] = ()
    serve: tuple[str, ...] = ()
    query: tuple[str, ...] = ()
    token: tuple[str, ...] = ()
    watch: tuple[str, ...] = ()
    note: str = ""

    def with_own_runtime(self, role: Role, node: str | None = None) -> RolePermissions:
        """Add what every service runtime does: stats, health queryable and liveliness token of its role
        (of its node only, for a node-bound role)."""
        r = role.value if node is None else f"{role.value}/{check_name(node, 'node')}"
        return RolePermissions(
            common_name=self.common_name,
            put=(*self.put, f"{ROOT}/stats/{r}/**"),
            subscribe=self.subscribe,
            serve=(*self.serve, f"{ROOT}/health/{r}/**"),
            query=self.query,
            token=(*self.token, f"{ROOT}/alive/{r}/**"),
            watch=self.watch,
            note=self.note,
        )


@dataclass(frozen=True)
class PolicySettings:
    """Which UAVs exist, and which of them get simulated odometry from their camera on ``pose/vo``."""

    uavs: tuple[str, ...] = DEFAULT_UAVS
    #: the nodes whose foreman and workers may join (each its own certificate, ``foreman.{node}``)
    nodes: tuple[str, ...] = DEFAULT_NODES
    #: the office flight has no estimator: its camera publishes the simulator's odometry on pose/vo
    camera_odometry_uavs: tuple[str, ...] = ("uav1",)
    extra_client_names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        for uav in (*self.uavs, *self.camera_odometry_uavs):
            check_name(uav, "uav")
        for node in self.nodes:
            check_name(node, "node")


def uav_common_name(role: Role, uav: str) -> str:
    """CN of a UAV-bound role's certificate, e.g. ``camera.uav0``."""
    return f"{role.value}.{check_name(uav, 'uav')}"


def node_common_name(role: Role, node: str) -> str:
    """CN of a node-bound role's certificate, e.g. ``foreman.h1``."""
    return f"{role.value}.{check_name(node, 'node')}"


def common_names(uavs: Iterable[str], nodes: Iterable[str]) -> list[str]:
    """Every certificate common name of a deployment of these UAVs and nodes."""
    per_uav = [uav_common_name(r, u) for u in uavs for r in UAV_ROLES]
    per_node = [node_common_name(r, n) for n in nodes for r in NODE_ROLES]
    return [*per_uav, *per_node, *GLOBAL_NAMES]


def role_table(settings: PolicySettings | None = None) -> list[RolePermissions]:
    """Every certificate common name and its permissions (docs/security.md's table, generated from here)."""
    s = settings or PolicySettings()
    out: list[RolePermissions] = []
    for uav in s.uavs:
        sensors = (keys.camera_key(uav), keys.imu_key(uav), keys.range_key(uav))
        odometry = (keys.pose_vo_key(uav),) if uav in s.camera_odometry_uavs else ()
        out.append(
            RolePermissions(
                uav_common_name(Role.CAMERA, uav),
                # its stream's rig: published, and answered to late joiners
                put=(*sensors, *odometry, keys.rig_key(uav)),
                subscribe=(keys.yaw_key(uav),),
                serve=(keys.rig_key(uav),),
                watch=(keys.alive_role(Role.MASTER),),
                note="its UAV's camera, imu, range" + (" (+ simulated pose/vo)" if odometry else ""),
            ).with_own_runtime(Role.CAMERA)
        )
        out.append(
            RolePermissions(
                uav_common_name(Role.MASTER, uav),
                put=(keys.yaw_key(uav),),
                # its own UAV's yaw: a standby continues from the active master's; imu: the gyro prior
                subscribe=(keys.camera_key(uav), keys.imu_key(uav), keys.yaw_key(uav), keys.rig_key(uav)),
                # the other masters' health: a standby learns the active master's session id there
                query=(FOREMAN_WORK, WORKER_WORK, f"{ROOT}/health/{Role.MASTER.value}/**", keys.rig_key(uav)),
                token=(keys.election_all(uav),),
                watch=(keys.ALIVE_ALL, keys.election_all(uav)),
                note="its UAV's yaw and election; queries foremen and workers",
            ).with_own_runtime(Role.MASTER)
        )
        out.append(
            RolePermissions(
                uav_common_name(Role.ESTIMATOR, uav),
                put=(keys.attitude_key(uav), keys.pose_vo_key(uav)),
                subscribe=(
                    keys.camera_key(uav),
                    keys.imu_key(uav),
                    keys.range_key(uav),
                    keys.yaw_key(uav),
                    keys.rig_key(uav),
                ),
                query=(keys.rig_key(uav),),
                note="its UAV's attitude and pose/vo",
            ).with_own_runtime(Role.ESTIMATOR)
        )
        out.append(
            RolePermissions(
                uav_common_name(Role.LOCALIZER, uav),
                put=(keys.pose_pf_key(uav),),
                subscribe=(keys.camera_key(uav), keys.pose_vo_key(uav), keys.imu_key(uav), keys.rig_key(uav)),
                query=(keys.rig_key(uav),),
                note="its UAV's pose/pf",
            ).with_own_runtime(Role.LOCALIZER)
        )
    for node in s.nodes:
        out.append(
            RolePermissions(
                node_common_name(Role.FOREMAN, node),
                serve=(keys.foreman_key(node),),
                query=(f"{ROOT}/node/{node}/worker/*",),
                watch=(keys.alive_node_workers(node),),
                note=f"serves {node}'s blocks; queries {node}'s workers",
            ).with_own_runtime(Role.FOREMAN, node)
        )
        out.append(
            RolePermissions(
                node_common_name(Role.WORKER, node),
                serve=(f"{ROOT}/node/{node}/worker/*",),
                note=f"serves {node}'s patches",
            ).with_own_runtime(Role.WORKER, node)
        )
    readable = tuple(f"{ROOT}/uav/*/{topic}" for topic in OUTPUTS)
    for name in ("client", *s.extra_client_names):
        out.append(
            RolePermissions(
                name,
                subscribe=(*readable, keys.STATS_ALL),
                query=(keys.HEALTH_ALL,),
                watch=(keys.ALIVE_ALL, f"{ROOT}/elect/**"),
                note="read-only: subscribes to outputs, stats; health; watches membership and elections",
            )
        )
    out.append(RolePermissions(Role.ROUTER.value, note="forwards for everybody (peers trust its filtering)"))
    return out


def _rule(rule_id: str, flow: str, messages: Sequence[str], key_exprs: Iterable[str]) -> dict[str, Any]:
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": [flow],
        "messages": list(messages),
        "key_exprs": sorted(set(key_exprs)),
    }


def _declared_to(own: Sequence[str], patterns: Iterable[str]) -> tuple[str, ...]:
    """The declarations a participant with keys ``own`` may receive: its own keys and every other role's
    pattern that intersects one of them. Zenoh matches a declaration by *inclusion* in a rule, so without
    the patterns a client's ``capataz/uav/*/yaw`` subscription never reaches the master that puts
    ``capataz/uav/uav0/yaw`` and the client receives nothing (the data itself is still checked per key)."""
    wider = {p for p in patterns if any(zenoh.KeyExpr(p).intersects(zenoh.KeyExpr(k)) for k in own)}
    return tuple(own) + tuple(sorted(wider - set(own)))


def _rules_of(role: RolePermissions, table: Sequence[RolePermissions] = ()) -> list[dict[str, Any]]:
    cn = role.common_name
    subscriptions = [k for r in table for k in r.subscribe]
    queries = [k for r in table for k in r.query]
    watches = [k for r in table for k in r.watch]
    wanted: list[tuple[str, str, tuple[str, ...], tuple[str, ...]]] = [
        # what it may send (ingress at its neighbours)
        ("in-put", "ingress", ("put",), role.put),
        ("in-sub", "ingress", ("declare_subscriber",), role.subscribe),
        ("in-serve", "ingress", ("declare_queryable", "reply"), role.serve),
        ("in-query", "ingress", ("query",), role.query),
        ("in-token", "ingress", ("liveliness_token",), role.token),
        ("in-watch", "ingress", ("declare_liveliness_subscriber", "liveliness_query"), role.watch),
        # what it may receive, and the declarations its neighbours send it (egress at its neighbours)
        ("out-put", "egress", ("put",), role.subscribe),
        ("out-sub", "egress", ("declare_subscriber",), _declared_to(role.put, subscriptions)),
        ("out-query", "egress", ("query",), _declared_to(role.serve, queries)),
        ("out-serve", "egress", ("declare_queryable", "reply"), role.query),
        ("out-token", "egress", ("liveliness_token",), role.watch),
        (
            "out-watch",
            "egress",
            ("declare_liveliness_subscriber", "liveliness_query"),
            _declared_to(role.token, watches),
        ),
    ]
    return [_rule(f"{cn}:{suffix}", flow, messages, k) for suffix, flow, messages, k in wanted if k]


def acl_section(settings: PolicySettings | None = None) -> dict[str, Any]:
    """The ``access_control`` configuration of :func:`role_table` (deny by default)."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    table = role_table(settings)
    for role in table:
        cn = role.common_name
        if cn == Role.ROUTER.value:
            flows = ("ingress", "egress")
            own = [_rule(f"{cn}:{flow}", flow, ALL_MESSAGES, [f"{ROOT}/**"]) for flow in flows]
        else:
            own = _rules_of(role, table)
        rules.extend(own)
        subjects.append({"id": cn, "cert_common_names": [cn]})
        policies.append({"id": cn, "rules": [r["id"] for r in own], "subjects": [cn]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def markdown_table(settings: PolicySettings | None = None) -> str:
    """The role-permission table of docs/security.md."""
    lines = [
        "| certificate CN | put | subscribe | serve (queryable) | query | liveliness token | watch |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for role in role_table(settings):
        if role.common_name == Role.ROUTER.value:
            lines.append("| `router` | forwards all of `capataz/**` (the others' rules apply at its ingress) "
                         "| | | | | |")  # fmt: skip
            continue
        cells = [role.put, role.subscribe, role.serve, role.query, role.token, role.watch]
        text = [", ".join(f"`{k}`" for k in cell) or "-" for cell in cells]
        lines.append(f"| `{role.common_name}` | " + " | ".join(text) + " |")
    return "\n".join(lines)
