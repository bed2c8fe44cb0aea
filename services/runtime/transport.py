"""Zenoh sessions from settings, and the runtime every service shares.

- :class:`TransportSettings` (pydantic): mode, listen/connect endpoints, multicast scouting, shared memory,
  lease; also read from ``CAPATAZ_ZENOH_*`` environment variables (compose) -> :func:`open_session`.
- :class:`ServiceRuntime`: opens the session in a ``with``, declares ``capataz/alive/{role}/{node}/{i}``,
  answers ``capataz/health/...``, publishes :class:`~common.messages.Stats` periodically, and shuts down on
  SIGTERM/SIGINT within a second. Subclasses declare their own subscribers/queryables in :meth:`start`.
- Hand-off primitives so that callbacks never block: :class:`LatestSlot` (latest-wins, drops counted)
  and :class:`WorkQueue` (bounded FIFO, refusals counted).

It lives in ``services`` because it talks to Zenoh: ``common`` holds only pure cores.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar, Generic, Literal, TypeVar

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field

from common import keys
from common.errors import CapatazError
from common.messages import Health, Stats, WireError, WireModel, decode, encode, error_reply
from services.runtime import zconfig

logger = logging.getLogger(__name__)

ENV_PREFIX = "CAPATAZ_ZENOH_"
#: GIL switch interval of services (ZENOH.md: 10.7 ms -> 1.2 ms request latency next to a busy thread at
#: 0.5 ms). A zenoh thread that runs a reply/done callback while the service's thread works waits up to this
#: long for the GIL; 0.1 ms took 0.2-0.4 ms off a 752x480 master-foreman-worker frame (bench cluster),
#: 0.03 ms was no better.
SWITCH_INTERVAL_S = 0.0001
T = TypeVar("T")
M = TypeVar("M", bound=WireModel)


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
            raise TransportError(f"boolean environment value expected, got {text!r}")

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
        except ValueError as exc:
            raise TransportError(f"invalid transport settings: {exc}") from None

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
        }
        if self.mode == "client" or self.connect:
            entries["connect/timeout_ms"] = self.connect_timeout_ms
        return entries


def open_session(settings: TransportSettings) -> zenoh.Session:
    """Open a session (the caller closes it, or uses it in a ``with``)."""
    try:
        return zenoh.open(settings.to_config())
    except Exception as exc:
        raise TransportError(
            f"cannot open zenoh session ({settings.mode}, connect={settings.connect}): {exc}"
        ) from exc


# ----------------------------------------------------------------------------------------------- hand-off
class LatestSlot(Generic[T]):
    """Holds the newest item only: ``put`` never blocks, a replaced item is counted as dropped."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: T | None = None
        self.dropped = 0

    def put(self, item: T) -> bool:
        """Store ``item``; returns True if it replaced an unread one."""
        with self._cond:
            replaced = self._item is not None
            if replaced:
                self.dropped += 1
            self._item = item
            self._cond.notify()
            return replaced

    def take(self, timeout_s: float) -> T | None:
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout_s)
            item, self._item = self._item, None
            return item

    def depth(self) -> int:
        return 0 if self._item is None else 1


class WorkQueue(Generic[T]):
    """Bounded FIFO: ``offer`` never blocks and returns False when full (the caller counts/refuses)."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise TransportError("queue capacity must be >= 1")
        self._items: deque[T] = deque()
        self._capacity = capacity
        self._cond = threading.Condition()

    def offer(self, item: T) -> bool:
        with self._cond:
            if len(self._items) >= self._capacity:
                return False
            self._items.append(item)
            self._cond.notify()
            return True

    def take(self, timeout_s: float) -> T | None:
        with self._cond:
            if not self._items:
                self._cond.wait(timeout_s)
            return self._items.popleft() if self._items else None

    def drain(self) -> list[T]:
        with self._cond:
            items = list(self._items)
            self._items.clear()
            return items

    def depth(self) -> int:
        return len(self._items)


class Counters:
    """Thread-safe named counters and recent timings (for stats)."""

    def __init__(self, window: int = 200) -> None:
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._timings: dict[str, deque[float]] = {}
        self._window = window

    def inc(self, name: str, n: int = 1) -> int:
        with self._lock:
            value = self._counts.get(name, 0) + n
            self._counts[name] = value
            return value

    def get(self, name: str) -> int:
        with self._lock:
            return self._counts.get(name, 0)

    def time_ms(self, name: str, value_ms: float) -> None:
        with self._lock:
            self._timings.setdefault(name, deque(maxlen=self._window)).append(value_ms)

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def median_timings_ms(self) -> dict[str, float]:
        with self._lock:
            return {k: float(np.median(v)) for k, v in self._timings.items() if v}


# ----------------------------------------------------------------------------------------------- decoding
def zbytes(value: Any) -> bytes | None:
    """``ZBytes | None`` -> ``bytes | None``."""
    return None if value is None else value.to_bytes()


def source_of(sample: zenoh.Sample) -> str | None:
    """The source a sample *declares* (``zid/eid`` of its publisher), None when it declares none.

    Zenoh 1.10 gives a Python subscriber no transport-authenticated sender: this is what the publisher
    chose to attach (the capataz camera does), so it separates senders but does not authenticate them.
    """
    info = sample.source_info
    source = None if info is None else info.source_id
    return None if source is None else f"{source.zid}/{source.eid}"


class ServiceRuntime:
    """Base of every service: session, liveliness, health, stats, signals, clean shutdown.

    Subclasses set :attr:`role`, override :meth:`start` (declare subscribers/queryables, start threads;
    they must watch :attr:`stop_event`) and optionally :meth:`stop`, :meth:`shares`, :meth:`queue_depths`.
    """

    role: keys.Role = keys.Role.WORKER

    def __init__(
        self,
        node: str,
        index: int,
        transport: TransportSettings,
        stats_period_s: float = 1.0,
    ) -> None:
        self.node = keys.check_name(node, "node")
        self.index = index
        self.transport = transport
        self.stats_period_s = stats_period_s
        self.counters = Counters()
        self.stop_event = threading.Event()
        self.started = threading.Event()
        self.session: zenoh.Session | None = None
        self._t0 = time.monotonic()
        self._threads: list[threading.Thread] = []
        self._log_lock = threading.Lock()

    # -- identity -------------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return f"{self.role.value}/{self.node}/{self.index}"

    # -- hooks ----------------------------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> None:
        """Declare subscribers/queryables and start threads."""

    def stop(self) -> None:
        """Release resources after :attr:`stop_event` is set (threads are joined by the runtime)."""

    def shares(self) -> dict[str, float]:
        return {}

    def queue_depths(self) -> dict[str, int]:
        return {}

    def healthy(self) -> tuple[bool, str]:
        return True, "ok"

    # -- helpers for subclasses -----------------------------------------------------------------------
    def undeclare_all(self, entities: Iterable[Any]) -> None:
        """Undeclare subscribers, publishers and queryables (``None`` skipped); failures are counted."""
        for entity in entities:
            if entity is None:
                continue
            try:
                entity.undeclare()
            except Exception as exc:
                self.count_error("undeclare_failures", "undeclare", exc)

    def spawn(self, target: Callable[[], None], name: str) -> threading.Thread:
        thread = threading.Thread(target=self._guard(target), name=f"{self.name}:{name}", daemon=True)
        self._threads.append(thread)
        thread.start()
        return thread

    def _guard(self, target: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                target()
            except Exception:
                logger.exception("%s: thread crashed; stopping the service", self.name)
                self.counters.inc("thread_crashes")
                self.stop_event.set()

        return run

    def count_error(self, counter: str, what: str, exc: BaseException | str) -> None:
        """Count an error and log it (every one of the first 20, then every 100th, with the count)."""
        n = self.counters.inc(counter)
        if n <= 20 or n % 100 == 0:
            logger.warning("%s: %s (%s #%d): %s", self.name, what, counter, n, exc)

    def decode_sample(self, sample: zenoh.Sample, expected: type[M]) -> M | None:
        """Decode a subscription sample; a bad one is counted and logged, and None returned."""
        try:
            return decode(zbytes(sample.payload), zbytes(sample.attachment), expected)
        except WireError as exc:
            self.count_error("malformed", f"bad message on {sample.key_expr}", exc)
            return None

    def decode_query(self, query: zenoh.Query, expected: type[M]) -> M | None:
        """Decode a query; a bad one gets an error reply (and is counted), and None is returned.

        The query is dropped when it was answered with an error.
        """
        try:
            return decode(zbytes(query.payload), zbytes(query.attachment), expected)
        except WireError as exc:
            self.count_error("malformed", f"bad query on {query.key_expr}", exc)
            self.reply_error(query, "malformed", str(exc))
            return None

    def serve_queries(
        self, queryable: Any, expected: type[M], handle: Callable[[zenoh.Query, M, float], None]
    ) -> None:
        """Drain a queryable declared with a FIFO channel until it is undeclared or the service stops.

        Each query is counted and decoded (a bad one is answered with an error and counted), then handed to
        ``handle(query, message, t_recv)`` with ``t_recv`` its ``time.perf_counter()`` arrival.
        """
        channel = queryable.handler
        while not self.stop_event.is_set():
            try:
                query = channel.recv()
            except zenoh.ZError:
                return  # queryable undeclared: shutting down
            t_recv = time.perf_counter()
            self.counters.inc("queries")
            message = self.decode_query(query, expected)
            self.counters.time_ms("decode", (time.perf_counter() - t_recv) * 1e3)
            if message is not None:
                handle(query, message, t_recv)

    def member_event(self, sample: zenoh.Sample) -> tuple[keys.MemberId, bool] | None:
        """The member of a liveliness sample and whether it joined (PUT) or left; a bad key is counted."""
        try:
            member = keys.parse_alive_key(str(sample.key_expr))
        except CapatazError as exc:
            self.count_error("bad_liveliness", "ignoring liveliness key", exc)
            return None
        return member, sample.kind == zenoh.SampleKind.PUT

    def reply_error(self, query: zenoh.Query, kind: str, text: str) -> None:
        try:
            query.reply_err(error_reply(kind, text))
        except Exception as exc:
            self.count_error("reply_failures", "cannot send error reply", exc)
        finally:
            query.drop()

    def reply(self, query: zenoh.Query, message: WireModel) -> None:
        payload, attachment = encode(message)
        try:
            query.reply(query.key_expr, payload, attachment=attachment)
        except Exception as exc:
            self.count_error("reply_failures", "cannot send reply", exc)
        finally:
            query.drop()

    # -- lifecycle ------------------------------------------------------------------------------------
    def stats_message(self) -> Stats:
        return Stats(
            role=self.role.value,
            node=self.node,
            index=self.index,
            stamp_s=time.time(),
            uptime_s=time.monotonic() - self._t0,
            counters=self.counters.counts(),
            timings_ms=self.counters.median_timings_ms(),
            queue_depths=self.queue_depths(),
            shares=self.shares(),
        )

    def _on_health(self, query: zenoh.Query) -> None:
        ok, detail = self.healthy()
        health = Health(
            role=self.role.value,
            node=self.node,
            index=self.index,
            ok=ok and not self.stop_event.is_set(),
            uptime_s=time.monotonic() - self._t0,
            detail=detail,
            counters=self.counters.counts(),
        )
        self.reply(query, health)

    def request_stop(self, *_args: Any) -> None:
        self.stop_event.set()

    @contextmanager
    def _signals(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, self.request_stop)
        # The handlers stay installed after run() returns: a SIGTERM that arrives while the process is
        # already exiting (a camera that finished its flight) must not turn a clean exit into -SIGTERM.
        yield

    def run(self) -> int:
        """Run until SIGTERM/SIGINT or :meth:`request_stop`; returns an exit code."""
        # hand-offs between zenoh's callback threads and ours wait for the GIL switch interval (5 ms by
        # default) whenever another thread runs Python code; 0.5 ms keeps a hop well under a millisecond
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        with self._signals(), open_session(self.transport) as session:
            self.session = session
            health = session.declare_queryable(
                keys.health_key(self.role, self.node, self.index), self._on_health, complete=True
            )
            stats_pub = session.declare_publisher(keys.stats_key(self.role, self.node, self.index))
            token = None
            try:
                self.start(session)
                # liveliness last: a member that is seen alive already answers its work and health keys
                token = session.liveliness().declare_token(keys.alive_key(self.role, self.node, self.index))
                self.started.set()
                logger.info("%s: up (%s)", self.name, self.transport.mode)
                while not self.stop_event.wait(self.stats_period_s):
                    payload, attachment = encode(self.stats_message())
                    stats_pub.put(payload, attachment=attachment)
            finally:
                self.stop_event.set()
                self.stop()
                deadline = time.monotonic() + 0.5
                for thread in self._threads:
                    thread.join(max(0.0, deadline - time.monotonic()))
                for entity in (token, stats_pub, health):
                    if entity is None:
                        continue
                    try:
                        entity.undeclare()
                    except Exception as exc:
                        logger.debug("%s: undeclare: %s", self.name, exc)
                timings = {k: round(v, 3) for k, v in self.counters.median_timings_ms().items()}
                logger.info("%s: stopped %s, median ms %s", self.name, self.counters.counts(), timings)
        return 1 if self.counters.get("thread_crashes") else 0


# ----------------------------------------------------------------------------------------------- CLI
def add_transport_arguments(parser: Any, node_default: str = "local") -> None:
    """Options every service shares (environment ``CAPATAZ_ZENOH_*`` fills what is not given)."""
    group = parser.add_argument_group("transport (defaults from CAPATAZ_ZENOH_* environment variables)")
    group.add_argument("--mode", choices=["peer", "client", "router"], help="zenoh mode (default peer)")
    group.add_argument("--listen", action="append", metavar="ENDPOINT", help="listen endpoint (repeatable)")
    group.add_argument("--connect", action="append", metavar="ENDPOINT", help="connect endpoint (repeatable)")
    group.add_argument(
        "--multicast", action=argparse.BooleanOptionalAction, help="multicast scouting on/off (default off)"
    )
    group.add_argument(
        "--shm", action=argparse.BooleanOptionalAction, help="zenoh shared memory on/off (default off)"
    )
    group.add_argument("--lease-ms", type=int, help="link lease in ms (default 2000)")
    group.add_argument(
        "--zenoh-config",
        type=Path,
        metavar="FILE",
        help="zenoh configuration file under these settings (access control, TLS, ...; env "
        "CAPATAZ_ZENOH_CONFIG); credentials only from it or CAPATAZ_ZENOH_TLS_{CA,CERT,KEY}, "
        "CAPATAZ_ZENOH_USRPWD_FILE",
    )
    group.add_argument("--node", default=node_default, help=f"node (host) name (default {node_default})")
    group.add_argument("--index", type=int, default=0, help="instance index on the node (default 0)")
    group.add_argument("--stats-period", type=float, default=1.0, help="seconds between stats messages")


def transport_from_args(args: Any) -> TransportSettings:
    return TransportSettings.from_env(
        mode=args.mode,
        listen=tuple(args.listen) if args.listen else None,
        connect=tuple(args.connect) if args.connect else None,
        multicast_scouting=args.multicast,
        shared_memory=args.shm,
        lease_ms=args.lease_ms,
        zenoh_config=getattr(args, "zenoh_config", None),
    )
