"""The base of every service: :class:`ServiceRuntime` opens the session in a ``with``, declares
``capataz/alive/{role}/{node}/{i}``, answers ``capataz/health/...``, publishes
:class:`~common.wire.messages.Stats` periodically, and shuts down on SIGTERM/SIGINT within a second.
Subclasses declare their own subscribers/queryables in :meth:`ServiceRuntime.start`."""

from __future__ import annotations

import logging
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, ClassVar, Generic, Self, TypeVar

import zenoh

from common.errors import CapatazError
from common.members import MemberId, Role, check_name
from common.wire import keys
from common.wire.codec import decode, encode, error_reply
from common.wire.messages import Health, Stats
from common.wire.schema import WireError, WireModel
from services.runtime.cli import transport_from_args
from services.runtime.counters import Counters
from services.runtime.presence import ConnectionMonitor, TokenWatch
from services.runtime.transport import TransportSettings, open_session, zbytes

logger = logging.getLogger(__name__)

#: GIL switch interval of services (ZENOH.md: 10.7 ms -> 1.2 ms request latency next to a busy thread at
#: 0.5 ms). A zenoh thread that runs a reply/done callback while the service's thread works waits up to this
#: long for the GIL; 0.1 ms took 0.2-0.4 ms off a 752x480 master-foreman-worker frame (bench cluster),
#: 0.03 ms was no better.
SWITCH_INTERVAL_S = 0.0001
#: the machine a member runs on, in its stats (``capataz status``'s host column)
HOST_NAME = socket.gethostname()
M = TypeVar("M", bound=WireModel)


class ServiceRuntime:
    """Base of every service: session, liveliness, health, stats, signals, clean shutdown.

    Subclasses set :attr:`role`, override :meth:`start` (declare subscribers/queryables, start threads;
    they must watch :attr:`stop_event`) and optionally :meth:`stop`, :meth:`shares`, :meth:`queue_depths`.
    """

    #: every concrete service names its role (its liveliness, stats and health keys); there is no default
    role: ClassVar[Role]
    #: the ``--trajectory`` files of a service that publishes estimates (services/runtime/trajectory.py),
    #: or None
    trajectory_tap: Any = None

    def __init__(
        self,
        node: str,
        index: int,
        transport: TransportSettings,
        stats_period_s: float = 1.0,
    ) -> None:
        if not isinstance(getattr(type(self), "role", None), Role):
            raise TypeError(f"{type(self).__name__} must set its role (a Role) as a class attribute")
        self.node = check_name(node, "node")
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
        #: subscribers (and queryables) the default :meth:`stop` undeclares before the threads are joined.
        #: Publishers stay declared until the session closes: a thread may still be publishing (undeclaring
        #: them in stop() raced with it: "ZError: Undeclared publisher", a traceback and exit 1)
        self.subscriptions: list[Any] = []

    # -- identity -------------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return f"{self.role.value}/{self.node}/{self.index}"

    # -- hooks ----------------------------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> None:
        """Declare subscribers/queryables and start threads."""

    def stop(self) -> None:
        """Release resources after :attr:`stop_event` is set (threads are joined by the runtime); by
        default, undeclare :attr:`subscriptions`."""
        self.undeclare_all(self.subscriptions)

    def shares(self) -> dict[str, float]:
        return {}

    def queue_depths(self) -> dict[str, int]:
        return {}

    def healthy(self) -> tuple[bool, str]:
        return True, "ok"

    def uavs(self) -> tuple[str, ...]:
        """The UAV streams this member serves (its settings' ``uav`` or ``uavs``), empty for all streams."""
        settings = getattr(self, "settings", None)
        many = getattr(settings, "uavs", None)
        one = getattr(settings, "uav", None)
        return tuple(many) if many else (one,) if isinstance(one, str) else ()

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

    def publish(
        self,
        publisher: Any,
        message: WireModel,
        encoded: tuple[bytes, bytes] | None = None,
        **options: Any,
    ) -> bool:
        """Encode and put ``message`` (``encoded``: its ``(payload, attachment)`` when the sender already
        encoded it, e.g. to count its bytes; ``options``: zenoh's ``put`` keywords); False when the put failed
        because the service is stopping (the session closes under a thread still publishing). Other failures
        raise. (One function: a frame's walk enters this module once to publish.)"""
        payload, attachment = encoded if encoded is not None else encode(message)
        try:
            publisher.put(payload, attachment=attachment, **options)
        except zenoh.ZError:
            if self.stop_event.is_set():
                return False
            raise
        return True

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

    def count_failure(self, counter: str, what: str, exc: BaseException) -> None:
        """A step that failed and is recovered from: an expected failure (a :class:`CapatazError`: a member
        timed out, a job was refused) is counted under ``counter``; anything else is a bug in capataz,
        counted as ``internal_errors`` and logged with its traceback, never passed off as routine."""
        if isinstance(exc, CapatazError):
            self.count_error(counter, what, exc)
            return
        n = self.counters.inc("internal_errors")
        logger.error("%s: %s (internal error #%d, recovered: %s)", self.name, what, n, counter, exc_info=exc)

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
        ``handle(query, message, received_perf_s)``: its arrival on the ``time.perf_counter()`` clock.
        """
        channel = queryable.handler
        while not self.stop_event.is_set():
            try:
                query = channel.recv()
            except zenoh.ZError:
                return  # queryable undeclared: shutting down
            received_perf_s = time.perf_counter()
            self.counters.inc("queries")
            message = self.decode_query(query, expected)
            self.counters.time_ms("decode", (time.perf_counter() - received_perf_s) * 1e3)
            if message is not None:
                handle(query, message, received_perf_s)

    def member_event(self, sample: zenoh.Sample) -> tuple[MemberId, bool] | None:
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

    def reply(self, query: zenoh.Query, message: WireModel, key: str | None = None) -> None:
        """Answer ``query`` with ``message`` on ``key`` (default: the query's key expression)."""
        payload, attachment = encode(message)
        try:
            query.reply(query.key_expr if key is None else key, payload, attachment=attachment)
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
            cpu_s=time.process_time(),
            counters=self.counters.counts(),
            timings_ms=self.counters.median_timings_ms(),
            queue_depths=self.queue_depths(),
            shares=self.shares(),
            host=HOST_NAME,
            uavs=list(self.uavs()),
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
        # on its own key, not the query's: replies to ``capataz/health/**`` on one key were merged by the
        # default consolidation (1 of 12 members answered)
        self.reply(query, health, keys.health_key(self.role, self.node, self.index))

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
        # default) whenever another thread runs Python code: SWITCH_INTERVAL_S (0.1 ms) keeps a hop short
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        with self._signals(), open_session(self.transport) as session:
            self.session = session
            watch = TokenWatch(session, keys.alive_key(self.role, self.node, self.index))
            health = session.declare_queryable(
                keys.health_key(self.role, self.node, self.index), self._on_health, complete=True
            )
            stats_pub = session.declare_publisher(keys.stats_key(self.role, self.node, self.index))
            token = None
            try:
                watch.refuse_duplicate(self.name, self.transport.lease_ms, self.stop_event)
                self.start(session)
                # liveliness last: a member that is seen alive already answers its work and health keys
                token = session.liveliness().declare_token(keys.alive_key(self.role, self.node, self.index))
                self.started.set()
                logger.info(
                    "%s: up (%s, zid %s), listen %s, connect %s",
                    self.name,
                    self.transport.mode,
                    session.info.zid(),
                    ", ".join(self.transport.listen) or "none",
                    ", ".join(self.transport.connect) or "none",
                )
                monitor = ConnectionMonitor(self.name, self.transport.connect, self.role is Role.ROUTER)
                while not self.stop_event.wait(self.stats_period_s):
                    monitor.check(session)
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


S = TypeVar("S")


class ConfiguredService(ServiceRuntime, Generic[S]):
    """A service built from its settings: ``Service(node, index, transport, settings, stats_period_s)``.

    The runtime part is the base's; :attr:`settings` holds the service's own, and :meth:`setup` (called once,
    at the end of construction) builds what the service derives from them.
    """

    def __init__(
        self, node: str, index: int, transport: TransportSettings, settings: S, stats_period_s: float = 1.0
    ) -> None:
        super().__init__(node, index, transport, stats_period_s)
        self.settings = settings
        self.setup()

    def setup(self) -> None:
        """Build the service's own state from :attr:`settings` (cores, queues, sources); no I/O yet."""

    @classmethod
    def from_args(cls, args: Any, settings: S) -> Self:
        """The service as its command line asks for: runtime options from ``args``, its own ``settings``."""
        return cls(args.node, args.index, transport_from_args(args), settings, args.stats_period)
