"""``capataz view``: a Foxglove WebSocket server (foxglove-sdk) on 127.0.0.1 that republishes, per UAV, what
a user wants to watch of a flight. Connect the Foxglove app to ``ws://127.0.0.1:8765`` and open
``deploy/foxglove/capataz.json`` (the layout).

Foxglove topics (``{key}`` = a Zenoh key of the UAV, e.g. ``capataz/uav/uav0/pose/pf``):

- ``/{key}`` of ``camera``: foxglove.RawImage (mono8), down-scaled to ``--image-width``, at most
  ``--image-rate`` Hz;
- ``/{key}`` of ``yaw``, ``attitude``, ``pose/vo``, ``pose/pf``, ``truth`` (simulated flights) and of every
  ``capataz/stats/...``: JSON, the whole message (covariances, timings) with its JSON Schema;
- ``/capataz/uav/{uav}/cluster``: JSON of each yaw's per-member shares and stage timings;
- ``/{key}/in_frame`` of each pose key: foxglove.PoseInFrame in frame ``world`` (Foxglove's 3D panel);
- ``/tf``: foxglove.FrameTransform ``world`` -> ``{uav}/vo``, ``{uav}/pf``, ``{uav}/truth``.

Channels are advertised when their first message arrives. The Zenoh callbacks only hand a sample off
(frames: to a latest-wins slot per UAV after the rate limit; the rest: to a bounded queue); one thread
decodes, converts and logs to the server. A malformed sample is counted and dropped.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any

import cv2
import zenoh
from pydantic import BaseModel, ConfigDict, Field

from common.errors import CapatazError
from common.members import Role
from common.recordings.mcap import json_schema, to_json
from common.wire import keys
from common.wire.messages import Frame, PoseEstimate, Stats, YawEstimate
from common.wire.schema import WireModel
from services.runtime.cli import add_transport_arguments, transport_from_args
from services.runtime.tap import KeyTap
from services.runtime.transport import TransportSettings
from services.tools.view.layout import layout_json
from services.tools.view.subprotocol import SubprotocolFront

logger = logging.getLogger(__name__)

#: what the cluster channel carries of a YawEstimate
CLUSTER_SCHEMA = {
    "type": "object",
    "title": "capataz.Cluster",
    "properties": {
        "stamp_s": {"type": "number"},
        "members": {"type": "object", "description": "patches per member in this frame"},
        "timings_ms": {"type": "object", "description": "stage timings and per-member speeds"},
        "dropped_frames": {"type": "integer"},
        "redispatched": {"type": "integer"},
    },
}


class ViewError(CapatazError):
    """The viewer cannot serve (its port is taken, its address is not this host's)."""


class ViewSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    host: str = "127.0.0.1"
    #: WebSocket port (0 = any free port)
    port: int = Field(default=8765, ge=0, le=65535)
    #: frames are down-scaled to at most this width (pixels)
    image_width: int = Field(default=376, ge=16)
    #: frames republished per UAV per second at most
    image_rate_hz: float = Field(default=5.0, gt=0.0)
    queue: int = Field(default=512, ge=1)


class ViewService(KeyTap):
    role = Role.VIEWER

    def __init__(
        self,
        node: str,
        index: int,
        transport: TransportSettings,
        settings: ViewSettings,
        stats_period_s: float = 1.0,
    ) -> None:
        super().__init__(node, index, transport, settings.queue, stats_period_s)
        self.settings = settings
        self._last_frame_s: dict[str, float] = {}
        self._channels: dict[str, Any] = {}
        self.server: Any = None
        self.front: SubprotocolFront | None = None
        self.context: Any = None

    # -- lifecycle -------------------------------------------------------------------------------------
    def tap_keys(self) -> tuple[str, ...]:
        return (f"{keys.ROOT}/uav/**", keys.STATS_ALL)

    def start(self, session: zenoh.Session) -> None:
        import foxglove

        self.context = foxglove.Context()
        try:  # the viewer's port first: a taken port is the user's to fix, before anything starts
            self.front = SubprotocolFront(self.settings.host, self.settings.port, backend_port=0)
        except OSError as exc:
            where = f"--port {self.settings.port}: cannot serve on {self.settings.host}"
            raise ViewError(f"{where}: {exc.strerror or exc}") from None
        # the SDK's server on an internal loopback port; the front answers both subprotocol names
        self.server = foxglove.start_server(name="capataz", host="127.0.0.1", port=0, context=self.context)
        self.front.backend_port = int(self.server.port)
        self.front.start()
        logger.info(
            "Foxglove WebSocket server on ws://%s:%d (foxglove.sdk.v1 and foxglove.websocket.v1)",
            self.settings.host,
            self.front.port,
        )
        super().start(session)

    def stop(self) -> None:
        super().stop()
        if self.front is not None:
            self.front.stop()
        if self.server is not None:
            self.server.stop()

    @property
    def port(self) -> int:
        return self.front.port if self.front is not None else 0

    def admit(self, key: str) -> bool:
        """Frames: at most ``image_rate_hz`` per UAV, decided before they are queued."""
        if not key.endswith("/camera"):
            return True
        now = time.monotonic()
        if now - self._last_frame_s.get(key, -1e9) < 1.0 / self.settings.image_rate_hz:
            self.counters.inc("frames_skipped")
            return False
        self._last_frame_s[key] = now
        return True

    def handle(self, key: str, message: WireModel, log_ns: int, publish_ns: int | None) -> None:
        self._republish(key, message, log_ns)

    def _channel(self, topic: str, kind: str, schema: dict[str, Any] | None = None) -> Any:
        channel = self._channels.get(topic)
        if channel is None:
            import foxglove
            from foxglove.channels import FrameTransformChannel, PoseInFrameChannel, RawImageChannel

            if kind == "image":
                channel = RawImageChannel(topic, context=self.context)
            elif kind == "pose":
                channel = PoseInFrameChannel(topic, context=self.context)
            elif kind == "tf":
                channel = FrameTransformChannel(topic, context=self.context)
            else:
                channel = foxglove.Channel(topic, schema=schema, context=self.context)
            self._channels[topic] = channel
            self.counters.inc("channels")
        return channel

    def _republish(self, key: str, message: WireModel, log_ns: int) -> None:
        from foxglove.messages import (
            FrameTransform,
            Pose,
            PoseInFrame,
            Quaternion,
            RawImage,
            Timestamp,
            Vector3,
        )

        topic = "/" + key
        if isinstance(message, Frame):
            pixels = message.pixels
            if message.width > self.settings.image_width:
                height = max(1, round(message.height * self.settings.image_width / message.width))
                pixels = cv2.resize(pixels, (self.settings.image_width, height), interpolation=cv2.INTER_AREA)
            h, w = pixels.shape
            image = RawImage(
                timestamp=_stamp(message.stamp_s, Timestamp),
                frame_id=message.frame_id,
                width=w,
                height=h,
                encoding="mono8",
                step=w,
                data=pixels.tobytes(),
            )
            self._channel(topic, "image").log(image, log_time=log_ns)
            self.counters.inc("frames_out")
            return
        self._channel(topic, "json", json_schema(type(message))).log(to_json(message), log_time=log_ns)
        if isinstance(message, YawEstimate):
            cluster = {
                "stamp_s": message.stamp_s,
                "members": message.members,
                "timings_ms": message.timings_ms,
                "dropped_frames": message.dropped_frames,
                "redispatched": message.redispatched,
            }
            self._channel(topic.removesuffix("/yaw") + "/cluster", "json", CLUSTER_SCHEMA).log(
                cluster, log_time=log_ns
            )
        elif isinstance(message, PoseEstimate):
            p, q = message.p_world_body_m, message.q_world_body
            stamp = _stamp(message.stamp_s, Timestamp)
            position = Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))
            orientation = Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0]))
            pose = PoseInFrame(
                timestamp=stamp,
                frame_id=message.frame_id,
                pose=Pose(position=position, orientation=orientation),
            )
            self._channel(topic + "/in_frame", "pose").log(pose, log_time=log_ns)
            child = f"{message.uav}/{key.rsplit('/', 1)[-1]}"  # uav0/vo, uav0/pf, uav0/truth
            tf = FrameTransform(
                timestamp=stamp,
                parent_frame_id=message.frame_id,
                child_frame_id=child,
                translation=position,
                rotation=orientation,
            )
            self._channel("/tf", "tf").log(tf, log_time=log_ns)
        elif isinstance(message, Stats):
            pass  # the JSON above carries its counters, timings, queue depths and shares
        self.counters.inc("messages_out")


def _stamp(stamp_s: float, timestamp: Any) -> Any:
    ns = max(0, round(stamp_s * 1e9))
    return timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("view", help="Foxglove WebSocket server: watch each UAV's flight live")
    add_transport_arguments(parser, node_default="view")
    parser.add_argument("--host", default="127.0.0.1", help="WebSocket address (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765)")
    parser.add_argument("--image-width", type=int, default=376, help="frames down-scaled to this width")
    parser.add_argument("--image-rate", type=float, default=5.0, help="frames per second per UAV at most")
    parser.add_argument("--write-layout", type=Path, help="write the Foxglove layout (for --uav) and exit")
    parser.add_argument("--uav", default="uav0", help="UAV of the written layout (default uav0)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.write_layout is not None:
        args.write_layout.parent.mkdir(parents=True, exist_ok=True)
        args.write_layout.write_text(layout_json(args.uav))
        print(f"wrote {args.write_layout}")
        return 0
    settings = ViewSettings(
        host=args.host, port=args.port, image_width=args.image_width, image_rate_hz=args.image_rate
    )
    return ViewService(args.node, args.index, transport_from_args(args), settings, args.stats_period).run()
