"""A consumer's side of the rig that travels with a stream: the camera publishes its
:class:`~common.rig.Rig` on ``capataz/uav/{uav}/rig`` (and answers queries there, for late joiners) and puts
its ``rig_id`` in every frame's header; :class:`RigFollower` keeps the rigs it has received (a few, the
newest kept) and tells, for a frame, which rig it was taken with.

- Camera or mount options given to the service **override** the stream's rig: the service follows none
  (:func:`follow_stream_rig`).
- A frame without a ``rig_id`` (a stream of an older camera, a recording made before rigs travelled) is taken
  with the service's own options, as before.
- A frame whose rig the follower has not received is **refused** (``refused_camera_unknown_rig``, one line)
  and the rig is asked for again, at most once a second: a consumer never measures frames with a lens or a
  mount it does not know.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from typing import Any, Protocol

import zenoh

from common.rig import Rig
from common.wire import keys
from common.wire.messages import Frame
from common.wire.rig import RigMessage, rig_from_message
from services.runtime.camera_options import CameraOptions
from services.runtime.counters import Counters
from services.runtime.mount_options import MountOptions

logger = logging.getLogger(__name__)

#: rigs kept per stream (a camera reconfigured a few times); the oldest is forgotten beyond
KEPT = 8
#: a missing rig is asked for again at most this often (s)
REQUERY_S = 1.0


class _Service(Protocol):
    counters: Counters

    @property
    def name(self) -> str: ...

    def count_error(self, counter: str, what: str, exc: BaseException | str) -> None: ...

    def decode_sample(self, sample: zenoh.Sample, expected: type[RigMessage]) -> RigMessage | None: ...


def describe_rig(rig: Rig) -> str:
    """One log line's worth of a rig."""
    c = rig.camera
    return (
        f"rig {rig.rig_id}: {c.width}x{c.height} fx {c.fx:.2f} fy {c.fy:.2f} cx {c.cx:.2f} cy {c.cy:.2f} "
        f"{c.distortion.model.value} {list(c.distortion.coeffs)}, R_body_camera "
        f"{rig.R_body_camera.round(4).tolist()}, R_body_imu {rig.R_body_imu.round(4).tolist()}, "
        f"IMU clock offset {rig.time_offset_s:+.4f} s"
    )


class RigFollower:
    """The rigs of one UAV's stream as its camera publishes them; thread-safe."""

    def __init__(self, uav: str, service: _Service) -> None:
        self.uav = uav
        self._service = service
        self._rigs: OrderedDict[str, Rig] = OrderedDict()
        self._lock = threading.Lock()
        self._session: zenoh.Session | None = None
        self._asked_s = -float("inf")
        #: the last ask that waited for its replies: throttled on its own, so that the start's ask (which
        #: finds no camera yet) does not stop the first frame's wait for the rig it names
        self._waited_s = -float("inf")

    def start(self, session: zenoh.Session) -> Any:
        """Subscribe to the stream's rig and ask for it once (late joiners); returns the subscriber."""
        self._session = session
        # indirect=False: on zenoh's receiving thread, in arrival order with the frames a service takes
        # there (the estimator's): with zenoh's default (a Python thread per subscriber) the rig, published
        # before the first frame, reached the follower after it on a busy host, and the frame was refused
        handler = zenoh.handlers.Callback(self.on_sample, indirect=False)
        subscriber = session.declare_subscriber(keys.rig_key(self.uav), handler)
        self.ask()
        return subscriber

    def ask(self, wait_s: float = 0.0) -> None:
        """Query the rig key (the camera answers with its current rig), at most once a :data:`REQUERY_S`;
        the replies arrive as samples, or, with ``wait_s``, are waited for up to that long (for a thread that
        may block, e.g. the master's frames thread: the camera's first publication can pass a subscription
        still being routed)."""
        session = self._session
        now = time.monotonic()
        last = self._waited_s if wait_s > 0.0 else self._asked_s
        if session is None or now - last < REQUERY_S:
            return
        self._asked_s = now
        if wait_s > 0.0:
            self._waited_s = now
        try:
            if wait_s <= 0.0:
                session.get(keys.rig_key(self.uav), self._on_reply, timeout=2.0)
                return
            for reply in session.get(keys.rig_key(self.uav), timeout=wait_s):
                self._on_reply(reply)
        except zenoh.ZError as exc:  # the session is closing
            logger.debug("%s: rig query: %s", self._service.name, exc)

    def _on_reply(self, reply: zenoh.Reply) -> None:
        if reply.ok is not None:
            self.on_sample(reply.ok)

    def on_sample(self, sample: zenoh.Sample) -> None:
        """A rig message (a publication or a query's reply): decoded, checked, kept, logged once."""
        message = self._service.decode_sample(sample, RigMessage)
        if message is None:
            return
        if message.uav != self.uav:
            self._service.count_error("refused_rig_foreign_uav", "rig of another UAV refused", message.uav)
            return
        self.add(rig_from_message(message))  # checked at decode: its id is its content's

    def add(self, rig: Rig) -> None:
        with self._lock:
            known = rig.rig_id in self._rigs
            self._rigs[rig.rig_id] = rig
            self._rigs.move_to_end(rig.rig_id)
            while len(self._rigs) > KEPT:
                self._rigs.popitem(last=False)
        if not known:
            self._service.counters.inc("rigs_received")
            logger.info("%s: the stream's %s", self._service.name, describe_rig(rig))

    def rig_of(self, frame: Frame, wait_s: float = 0.0) -> tuple[Rig | None, bool]:
        """``(rig, admitted)`` for a frame: the stream's rig of the frame's ``rig_id``, or None for a frame
        without one (the service's own options apply); ``admitted`` False when the frame names a rig not
        received (counted, logged, asked for; with ``wait_s``, asked for and waited for first)."""
        rig_id = frame.rig_id
        if rig_id is None:
            return None, True
        with self._lock:
            rig = self._rigs.get(rig_id)
        if rig is None and wait_s > 0.0:
            self.ask(wait_s)
            with self._lock:
                rig = self._rigs.get(rig_id)
        if rig is None:
            self._service.count_error(
                "refused_camera_unknown_rig", "frame refused", f"seq {frame.seq}: rig {rig_id} not received"
            )
            self.ask()
            return None, False
        return rig, True


def follow_stream_rig(
    uav: str, service: _Service, camera: CameraOptions, mount: MountOptions | None = None
) -> RigFollower | None:
    """The service's follower of ``uav``'s rig, or None when it was given camera (or mount) options: they
    override the stream's rig."""
    if camera.given or (mount is not None and mount != MountOptions()):
        return None
    return RigFollower(uav, service)
