"""The camera (replayer): one or more UAV streams at a given rate, once or looped.

A simulated flight publishes, in time order, every IMU and rangefinder sample up to a frame's stamp,
then the frame (:func:`common.sim.stream.flight_measurements`, through the one publish loop of
:mod:`services.camera.replay` that also replays recorded inputs). ``--flight office`` publishes the
localizer's default flight through the built-in office instead, from the localizer's forward-looking
camera, with the flight's simulated odometry on ``pose/vo`` (truth plus noise, source ``sim-odometry``):
no estimator can run on that flight, and paper B's prediction needs a velocity. ``--fps 0`` publishes as
fast as possible. ``--in-flight K`` is flow control for measurements: the camera keeps at most K frames
of a stream without a published yaw (so a run can check that every frame yields a yaw); 0 (the default)
is a free-running camera whose frames the master takes latest-wins.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from common.members import Role
from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import Frame, YawEstimate
from common.wire.rig import message_of_rig
from common.wire.schema import WireModel
from services.camera.flights import flight_source, write_flight_calibration
from services.camera.images import image_files
from services.camera.replay import replay_source
from services.camera.settings import CameraSettings, FlightName
from services.camera.sources import add_source_arguments, open_camera_source, preloaded
from services.runtime.cli import add_enum_argument, add_transport_arguments, parse_size
from services.runtime.fields import settings_from
from services.runtime.options import add_options
from services.runtime.rig_follow import describe_rig
from services.runtime.service import ConfiguredService

logger = logging.getLogger(__name__)


class CameraService(ConfiguredService[CameraSettings]):
    role = Role.CAMERA

    def setup(self) -> None:
        settings = self.settings
        # a recorded input is opened and checked before anything is published (one clear error otherwise)
        recorded = open_camera_source(settings)
        if recorded is not None and settings.preload:
            recorded = preloaded(recorded)
        self.source = recorded if recorded is not None else flight_source(settings)
        #: the rig published with the stream (its id in every frame's header); None: the source has none
        self.rig = self.source.stream_rig()
        self._acked: dict[str, int] = dict.fromkeys(settings.uavs, -1)
        self._ack = threading.Condition()
        self.finished = threading.Event()
        self._entities: list[Any] = []
        self._consumer_alive = threading.Event()

    def start(self, session: zenoh.Session) -> None:
        self._pub: dict[str, dict[str, Any]] = {}
        self._rig_pub: dict[str, Any] = {}
        for uav in self.settings.uavs:
            self._pub[uav] = {
                # free-running: DROP (real time, latest wins); flow-controlled replay: BLOCK (every frame)
                "camera": session.declare_publisher(
                    keys.camera_key(uav),
                    congestion_control=(
                        zenoh.CongestionControl.BLOCK
                        if self.settings.in_flight
                        else zenoh.CongestionControl.DROP
                    ),
                ),
                "imu": session.declare_publisher(keys.imu_key(uav)),
                "range": session.declare_publisher(keys.range_key(uav)),
                "pose_vo": session.declare_publisher(keys.pose_vo_key(uav)),
                "truth": session.declare_publisher(keys.truth_key(uav)),
            }
            self._entities.append(session.declare_subscriber(keys.yaw_key(uav), self._on_yaw))
        self._entities.append(
            session.liveliness().declare_subscriber(
                keys.alive_role(self.settings.wait_for), self._on_consumer, history=True
            )
        )
        if self.rig is not None:
            logger.info("%s: %s", self.name, describe_rig(self.rig))
            for uav in self.settings.uavs:
                self._entities.append(
                    session.declare_queryable(keys.rig_key(uav), self._on_rig_query, complete=True)
                )
                self._rig_pub[uav] = session.declare_publisher(keys.rig_key(uav))
                self._entities.append(self._rig_pub[uav])
        self.spawn(self._publish_all, "publish")

    def _on_rig_query(self, query: zenoh.Query) -> None:
        """A late joiner asks for the stream's rig: this camera's, for the UAV the key names."""
        assert self.rig is not None
        uav = str(query.key_expr).split("/")[2]
        if uav in self.settings.uavs:
            self.reply(query, message_of_rig(uav, self.rig, time.time()))

    def run(self) -> int:
        """The service's run; exit code 1 also when a recording broke half-way."""
        code = super().run()
        return code or (1 if self.counters.get("recording_errors") else 0)

    def _on_consumer(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self._consumer_alive.set()

    def _on_yaw(self, sample: zenoh.Sample) -> None:
        estimate = self.decode_sample(sample, YawEstimate)
        if estimate is None:
            return
        with self._ack:
            self._acked[estimate.uav] = max(self._acked.get(estimate.uav, -1), estimate.seq)
            self._ack.notify_all()

    def put(self, uav: str, topic: str, message: WireModel) -> bool:
        """Publish ``message`` on ``uav``'s ``topic`` (False: the service is stopping)."""
        publisher = self._pub[uav][topic]
        if isinstance(message, Frame):
            # the rig it was taken with, by id (the rig itself is on the rig key), and how it travels
            update = frame_codec_fields(self.settings)
            if self.rig is not None:
                update["rig_id"] = self.rig.rig_id
            message = message.model_copy(update=update)
            payload, attachment = encode(message)
            sent = self.counters.inc("frame_bytes_out", len(payload))
            if sent == len(payload):  # the first frame
                logger.info("%s: frames go out as %s", self.name, describe_frame(message, len(payload)))
            # declare the source: masters follow one camera per stream (SourceLock)
            source = zenoh.SourceInfo(publisher.id, message.seq)
            return self.publish(publisher, message, (payload, attachment), source_info=source)
        return self.publish(publisher, message)

    def wait_yaw(self, uav: str, seq: int) -> None:
        """Flow control: at most ``in_flight`` frames without a yaw."""
        if not self.settings.in_flight:
            return
        deadline = time.monotonic() + self.settings.yaw_timeout_s
        with self._ack:
            while self._acked[uav] < seq - self.settings.in_flight + 1 and not self.stop_event.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    self.counters.inc("yaw_timeouts")
                    return
                self._ack.wait(min(left, 0.1))

    def _publish_all(self) -> None:
        self._wait_for_consumer()
        # the rig goes out once the stream's routes exist, just before the first frame (same session, same
        # priority: it arrives first). Published at start, a consumer already up could miss it (its
        # subscription not yet routed to us) and refuse the first frames as naming an unknown rig.
        if self.rig is not None:
            for uav, publisher in self._rig_pub.items():
                self.publish(publisher, message_of_rig(uav, self.rig, time.time()))
        replay_source(self, self.source)

    def _wait_for_consumer(self) -> None:
        if self.settings.wait_master_s:
            deadline = time.monotonic() + self.settings.wait_master_s
            if not self._consumer_alive.wait(self.settings.wait_master_s):
                who = self.settings.wait_for.value
                self.count_error(f"no_{who}", f"no {who} alive; publishing anyway", "timeout")
            # it is alive: also wait until its frame subscription is routed to us
            while not self.stop_event.is_set() and time.monotonic() < deadline:
                if all(p["camera"].matching_status.matching for p in self._pub.values()):
                    break
                time.sleep(0.01)


def frame_codec_fields(settings: CameraSettings) -> dict[str, Any]:
    """The fields of a frame that say how it travels (``--frame-codec``, ``--jpeg-quality``)."""
    if settings.frame_codec == "jpeg":
        return {"encoding": "jpeg", "quality": settings.jpeg_quality}
    return {"encoding": settings.frame_codec}


def describe_frame(frame: Frame, payload_bytes: int) -> str:
    """``752x480 jpeg q90: 119.8 kB per frame (33 % of mono8's 361.0 kB)``."""
    raw = frame.width * frame.height
    codec = frame.encoding + (f" q{frame.quality}" if frame.quality is not None else "")
    size = f"{frame.width}x{frame.height} {codec}: {payload_bytes / 1e3:.1f} kB per frame"
    if frame.encoding == "mono8":
        return size
    return f"{size} ({100 * payload_bytes / raw:.0f} % of mono8's {raw / 1e3:.1f} kB)"


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("camera", help="publish a simulated flight (or images) for UAV streams")
    add_transport_arguments(parser, node_default="camera")
    parser.add_argument("--uav", action="append", help="UAV stream id (repeatable; default uav0)")
    add_enum_argument(
        parser, "--flight", FlightName, FlightName.HOVER,
        help="simulated flight: paper A's hover, paper C's turns (ground camera), the localizer's office, "
        "or a field scenario (checkerboard or tiled floor, distorted wide-angle lens, low altitude, blur; "
        "'field' combines them; 320x240; --write-calibration gives the master its lens)"
    )  # fmt: skip
    parser.add_argument(
        "--frames", type=int, default=2041, help="frames of the hover or office flight (default 2041)"
    )
    parser.add_argument("--seed", type=int, default=0, help="simulation seed")
    parser.add_argument("--fps", type=float, default=20.0, help="frames per second (0 = as fast as possible)")
    parser.add_argument("--loop", action="store_true", help="replay forever")
    parser.add_argument("--preload", action="store_true", help="read a whole recording before publishing")
    parser.add_argument(
        "--resolution",
        help="simulated camera WIDTHxHEIGHT, the flight's view kept (default: 752x480 hover and turns, "
        "320x240 field scenarios and office)",
    )
    parser.add_argument("--no-sensors", action="store_true", help="frames only (no IMU / rangefinder)")
    parser.add_argument(
        "--in-flight", type=int, default=0, help="max frames without a yaw (0 = free running)"
    )
    parser.add_argument(
        "--wait-master", dest="wait_master_s", type=float, default=10.0,
        help="seconds to wait for a master (or the --wait-for member) before the first frame (0: no wait)",
    )  # fmt: skip
    parser.add_argument(
        "--yaw-timeout", dest="yaw_timeout_s", type=float, default=5.0,
        help="with --in-flight: seconds a frame waits for its yaw before the next goes out anyway",
    )  # fmt: skip
    parser.add_argument(
        "--wait-for", choices=[r.value for r in (Role.MASTER, Role.ESTIMATOR, Role.LOCALIZER)],
        default=Role.MASTER.value,
        help="whose frame subscription to wait for (a camera feeding only a localizer or an estimator)",
    )  # fmt: skip
    parser.add_argument(
        "--write-calibration",
        type=Path,
        help="write the simulated flight's camera as an OpenCV YAML calibration (for the master's "
        "--calibration) and exit",
    )
    add_options(parser, CameraSettings, ("frame_codec", "jpeg_quality"))
    add_source_arguments(parser)
    parser.set_defaults(handler=run)


def camera_settings_from_args(args: argparse.Namespace) -> CameraSettings:
    width: int | None = None
    height: int | None = None
    if args.resolution is not None:
        width, height = parse_size(args.resolution, "--resolution", "752x480")
    # the simulation's and the recorded input's options (add_source_arguments) carry the fields' names
    return settings_from(
        CameraSettings,
        args,
        uavs=tuple(args.uav or ["uav0"]),
        width=width,
        height=height,
        sensors=not args.no_sensors,
    )


def run(args: argparse.Namespace) -> int:
    if args.write_calibration is not None:
        return write_flight_calibration(args.write_calibration, camera_settings_from_args(args))
    if args.images is not None:
        image_files(args.images)  # a wrong --images fails here, in one line, not in the publishing thread
    return CameraService.from_args(args, camera_settings_from_args(args)).run()
