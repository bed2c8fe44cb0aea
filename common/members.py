"""Cluster members as the cores know them: a :class:`Role`, a :class:`MemberId` (``role/node/i``) and the
name rule every key chunk obeys. The Zenoh keys built from them live in the wire ring
(:mod:`common.wire.keys`)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import StrEnum

from common.errors import InputError

_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")


class Topology(StrEnum):
    """Who a master dispatches to: every worker, or foremen that split blocks among their node's workers."""

    MASTER_WORKER = "master-worker"
    MASTER_FOREMAN_WORKER = "master-foreman-worker"


class Role(StrEnum):
    """Roles of services (the ``{role}`` part of liveliness, stats and health keys)."""

    CAMERA = "camera"
    MASTER = "master"
    FOREMAN = "foreman"
    WORKER = "worker"
    ROUTER = "router"
    ESTIMATOR = "estimator"
    LOCALIZER = "localizer"
    RECORDER = "recorder"
    VIEWER = "viewer"
    BRIDGE = "bridge"


def check_name(value: str, what: str = "name") -> str:
    """A key chunk: letters, digits, ``_ . -`` only (no ``/``, ``*``, ``$``, ``?``, ``#``)."""
    if not isinstance(value, str) or not _NAME.match(value):
        raise InputError(f"{what} must match [A-Za-z0-9_.-]+, got {value!r}")
    return value


def check_index(i: int) -> int:
    if isinstance(i, bool) or not isinstance(i, int) or i < 0:
        raise InputError(f"index must be a non-negative int, got {i!r}")
    return i


@dataclass(frozen=True, order=True)
class MemberId:
    """A service instance: ``role/node/i``; its name is used in shares and reports."""

    role: Role
    node: str
    index: int

    @property
    def name(self) -> str:
        return f"{self.role.value}/{self.node}/{self.index}"

    @classmethod
    def from_name(cls, name: str) -> MemberId:
        """Inverse of :attr:`name` (``role/node/i``); InputError otherwise."""
        parts = str(name).split("/")
        if len(parts) != 3:
            raise InputError(f"not a member name (role/node/i): {name!r}")
        try:
            role, index = Role(parts[0]), int(parts[2])
        except ValueError as exc:
            raise InputError(f"bad member name {name!r}: {exc}") from None
        return cls(role, check_name(parts[1], "node"), check_index(index))
