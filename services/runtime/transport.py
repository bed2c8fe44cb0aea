"""Zenoh sessions from settings: :class:`TransportSettings` (pydantic: mode, listen/connect endpoints,
multicast scouting, shared memory, lease; also read from ``CAPATAZ_ZENOH_*`` environment variables for
compose) -> :func:`open_session`, and :func:`listening_endpoints` / :func:`zbytes`.

The rest of the runtime lives beside it: :mod:`services.runtime.handoff` (LatestSlot, WorkQueue, Counters),
:mod:`services.runtime.service` (ServiceRuntime, ConfiguredService) and :mod:`services.runtime.cli`
(argparse helpers).
It lives in ``services`` because it talks to Zenoh: ``common`` holds only pure cores.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar, Literal

import zenoh
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common.errors import CapatazError
from services.runtime import zconfig
from services.runtime.usage import condense_validation_error

logger = logging.getLogger(__name__)

ENV_PREFIX = "CAPATAZ_ZENOH_"


class TransportError(CapatazError):
    """A session could not be opened or a transport setting is invalid."""


class TransportSettings(BaseModel):
    """How a service joins the Zenoh network."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: Literal["peer", "client", "router"] = "peer"
    #: endpoints to listen on; peers listen on loopback by default so they can be reached directly.
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    shared_memory: bool = False
    #: link lease (ms): a frozen peer is declared gone after about this long.
    lease_ms: int = Field(default=2000, ge=100)
    #: how long a client waits for its router at start (ms).
    connect_timeout_ms: int = Field(default=5000, ge=0)
    #: batches (64 KB each) of a link's data-priority transmit queue (zenoh's default is 2): with 2, a
    #: sender of a 1.5 MB share is blocked until most of it is on the socket, so the shares of a frame go
    #: out one after the other; with 16 they travel to the members in parallel.
    tx_queue_batches: int = Field(default=16, ge=1, le=16)
    #: zenoh's admin space (``@/<zid>/...``): needed to read the port a ``tcp/...:0`` listener was given
    #: (:func:`listening_endpoints`); off by default.
    admin_space: bool = False
    #: a Zenoh configuration file under these settings (see :mod:`services.runtime.zconfig`)
    zenoh_config: Path | None = None
    #: credentials: PEM files for mutual TLS, a ``user:password`` file; from the environment only
    tls_ca: Path | None = None
    tls_cert: Path | None = None
    tls_key: Path | None = None
    usrpwd_file: Path | None = None

    @classmethod
    def from_env(cls, environ: dict[str, str] | None = None, **overrides: Any) -> TransportSettings:
        """Settings from ``CAPATAZ_ZENOH_{MODE,LISTEN,CONNECT,MULTICAST,SHM,LEASE_MS,CONNECT_TIMEOUT_MS,
        TX_QUEUE_BATCHES,CONFIG,TLS_CA,TLS_CERT,TLS_KEY,USRPWD_FILE}`` (``CONFIG`` falls back to zenoh's
        ``ZENOH_CONFIG``).

        Endpoint lists are comma separated; booleans accept 1/0/true/false. ``overrides`` that are not
        None win over the environment.
        """
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}

        def flag(text: str) -> bool:
            low = text.strip().lower()
            if low in {"1", "true", "yes", "on"}:
                return True
            if low in {"0", "false", "no", "off"}:
                return False
            raise ValueError("must be one of 1/0/true/false/yes/no/on/off")

        table: dict[str, tuple[str, Callable[[str], Any]]] = {
            "MODE": ("mode", str.strip),
            "LISTEN": ("listen", lambda s: tuple(e.strip() for e in s.split(",") if e.strip())),
            "CONNECT": ("connect", lambda s: tuple(e.strip() for e in s.split(",") if e.strip())),
            "MULTICAST": ("multicast_scouting", flag),
            "SHM": ("shared_memory", flag),
            "LEASE_MS": ("lease_ms", int),
            "CONNECT_TIMEOUT_MS": ("connect_timeout_ms", int),
            "TX_QUEUE_BATCHES": ("tx_queue_batches", int),
            "TLS_CA": ("tls_ca", Path),
            "TLS_CERT": ("tls_cert", Path),
            "TLS_KEY": ("tls_key", Path),
            "USRPWD_FILE": ("usrpwd_file", Path),
        }
        if (config_path := zconfig.config_path_from_env(env)) is not None:
            values["zenoh_config"] = config_path
        for suffix, (field, parse) in table.items():
            if (text := env.get(ENV_PREFIX + suffix)) is not None:
                try:
                    values[field] = parse(text)
                except ValueError as exc:
                    raise TransportError(f"{ENV_PREFIX}{suffix}={text!r}: {exc}") from None
        values.update({k: v for k, v in overrides.items() if v is not None})
        try:
            return cls(**values)
        except ValidationError as exc:
            names = {f: f"--{s.lower().replace('_', '-')} / {ENV_PREFIX}{s}" for s, (f, _) in table.items()}
            text = condense_validation_error(exc, lambda field: names.get(field, field))
            raise TransportError(f"invalid transport settings: {text}") from None

    def to_config(self) -> zenoh.Config:
        """Zenoh's configuration: the config file (if any), these settings over it, then credentials.

        A key the file sets is kept unless the setting was given explicitly (``model_fields_set``).
        """
        try:
            config = zconfig.load_config(self.zenoh_config)
            entries = self._entries(config)
            entries.update(zconfig.tls_entries(self.tls_ca, self.tls_cert, self.tls_key))
            entries.update(zconfig.usrpwd_entries(self.usrpwd_file))
            for key, value in entries.items():
                zconfig.insert(config, key, value)
            zconfig.check_tls_ready(config, zconfig.get(config, "listen/endpoints") or [])
            zconfig.check_tls_trust(config, zconfig.get(config, "connect/endpoints") or [])
        except zconfig.ZenohConfigError as exc:
            raise TransportError(str(exc)) from None
        return config

    #: which setting decides which zenoh key (a file's value survives unless the setting was given)
    _FIELD_OF_KEY: ClassVar[dict[str, str]] = {
        "mode": "mode",
        "listen/endpoints": "listen",
        "connect/endpoints": "connect",
        "scouting/multicast/enabled": "multicast_scouting",
        "transport/shared_memory/enabled": "shared_memory",
        "transport/link/tx/lease": "lease_ms",
        "connect/timeout_ms": "connect_timeout_ms",
        "transport/link/tx/queue/size/data": "tx_queue_batches",
        "adminspace/enabled": "admin_space",
    }

    def _entries(self, base: zenoh.Config) -> dict[str, Any]:
        entries = self._own_entries()
        if self.zenoh_config is None:
            return entries
        explicit = self.model_fields_set
        return {
            key: value
            for key, value in entries.items()
            if self._FIELD_OF_KEY.get(key) in explicit or not zconfig.file_sets(base, key)
        }

    def _own_entries(self) -> dict[str, Any]:
        entries: dict[str, Any] = {
            "mode": self.mode,
            "listen/endpoints": list(self.listen),
            "connect/endpoints": list(self.connect),
            "scouting/multicast/enabled": self.multicast_scouting,
            "transport/shared_memory/enabled": self.shared_memory,
            "transport/link/tx/lease": self.lease_ms,
            "transport/link/tx/keep_alive": 4,
            "transport/link/tx/queue/size/data": self.tx_queue_batches,
            "adminspace/enabled": self.admin_space,
        }
        if self.mode == "client" or self.connect:
            entries["connect/timeout_ms"] = self.connect_timeout_ms
        return entries


def open_beyond_loopback(settings: TransportSettings) -> list[str]:
    """The endpoints of ``settings`` that are neither TLS nor on loopback (what any peer on the network can
    reach or be reached by without a certificate); empty when the session stays secure or local."""
    endpoints = [*settings.listen, *settings.connect]
    if settings.zenoh_config is not None or settings.tls_cert is not None:
        return []  # a configuration file or TLS credentials: the deployment chose its profile
    return [e for e in endpoints if not e.startswith(("tls/", "quic/")) and not _loopback(e)]


def _loopback(endpoint: str) -> bool:
    address = endpoint.split("/", 1)[-1].rsplit(":", 1)[0].strip("[]")
    return address in ("localhost", "::1") or address.startswith("127.")


def open_session(settings: TransportSettings) -> zenoh.Session:
    """Open a session (the caller closes it, or uses it in a ``with``); warns, at start, when the session is
    open (no TLS) on an endpoint beyond loopback: the open profile, for a lab."""
    if beyond := open_beyond_loopback(settings):
        logger.warning(
            "open profile: %s without TLS or access control; any peer that reaches it can read, forge and "
            "steer (a lab only; the default deployment is the secure profile)",
            ", ".join(beyond),
        )
    try:
        return zenoh.open(settings.to_config())
    except Exception as exc:
        raise TransportError(
            f"cannot open zenoh session ({settings.mode}, connect={settings.connect}): {exc}"
        ) from exc


def listening_endpoints(session: zenoh.Session, timeout_s: float = 5.0) -> tuple[str, ...]:
    """The endpoints ``session`` really listens on (``tcp/127.0.0.1:0`` resolved to its port).

    Read from the session's own admin space (``@/<zid>/peer`` or ``/router``), which must be enabled
    (:attr:`TransportSettings.admin_space`). Listening on port 0 and reading the port back is free of the
    race of reserving a port by binding and closing a socket first (another process may take it between).
    """
    zid = str(session.info.zid())
    for reply in session.get(f"@/{zid}/*", timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            info = json.loads(reply.ok.payload.to_bytes())
        except ValueError:
            continue
        if isinstance(info, dict) and info.get("locators"):
            return tuple(str(locator) for locator in info["locators"])
    raise TransportError(f"session {zid} reports no listening endpoint (is admin_space enabled?)")


def zbytes(value: Any) -> bytes | None:
    """``ZBytes | None`` -> ``bytes | None``."""
    return None if value is None else value.to_bytes()


def source_of(sample: zenoh.Sample) -> str | None:
    """The source a sample *declares* (``zid/eid`` of its publisher), None when it declares none.

    Zenoh 1.10 gives a Python subscriber no transport-authenticated sender: this is what the publisher
    chose to attach (the capataz camera does), so it separates senders but does not authenticate them.
    """
    info = getattr(sample, "source_info", None)  # a sample object without it declares nothing
    source = None if info is None else info.source_id
    return None if source is None else f"{source.zid}/{source.eid}"


def reply_channel(
    session: zenoh.Session,
    key: str | zenoh.KeyExpr,
    payload: bytes,
    attachment: bytes | None,
    timeout_s: float,
    cancellation_token: zenoh.CancellationToken | None = None,
) -> Any:
    """A query whose replies come through its own bounded FIFO channel (zenoh ends it at ``timeout_s`` with a
    "Timeout" error reply, or when ``cancellation_token`` is cancelled); every reply kept, blocking when the
    link is congested (a job must not be dropped)."""
    return session.get(
        key,
        zenoh.handlers.FifoChannel(2),
        payload=payload,
        attachment=attachment,
        timeout=timeout_s,
        consolidation=zenoh.ConsolidationMode.NONE,
        congestion_control=zenoh.CongestionControl.BLOCK,
        cancellation_token=cancellation_token,
    )
