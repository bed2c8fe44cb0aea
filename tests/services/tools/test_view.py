"""``capataz view`` tested with a client speaking the Foxglove WebSocket protocol (websockets + protobuf,
no mock of the SDK): it subscribes to every advertised channel and decodes each channel's messages with
the schema the server advertised (protobuf FileDescriptorSet or JSON Schema)."""

from __future__ import annotations

import base64
import json
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.sim.flight import hover_flight
from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import AttitudeEstimate, Frame, PoseEstimate, Stats
from common.wire.schema import WireModel
from services.runtime.transport import open_session
from services.tools.view import ViewService, ViewSettings
from tests.builders import yaw_estimate
from tests.zenoh_helpers import hub, peer

pytestmark = pytest.mark.zenoh


@pytest.fixture
def endpoint() -> Iterator[str]:
    with hub() as router:
        yield router


UAV = "uav0"


def _messages(k: int, flight: Any) -> list[tuple[str, WireModel]]:
    stamp = float(flight.frame_stamps_s[k % flight.n_frames])
    q = flight.q_world_body[0]
    pose = {"uav": UAV, "seq": k, "stamp_s": stamp, "p_world_body_m": [1.0, 2.0, 3.0], "q_world_body": q}
    yaw = {"uav": UAV, "seq": k, "stamp_s": stamp, "delta_yaw_rad": 0.01, "yaw_rad": 0.25, "inlier_count": 30,
           "confidence": 0.9, "timings_ms": {"total": 3.5}, "members": {"worker/h1/0": 40}}  # fmt: skip
    return [
        (
            keys.camera_key(UAV),
            Frame(
                uav=UAV, seq=k, stamp_s=stamp, width=752, height=480, pixels=flight.frame(k % flight.n_frames)
            ),
        ),
        (
            keys.yaw_key(UAV),
            yaw_estimate(**yaw),
        ),
        (
            keys.attitude_key(UAV),
            AttitudeEstimate(uav=UAV, seq=k, stamp_s=stamp, q_world_body=q, covariance=np.eye(3) * 1e-4),
        ),
        (keys.pose_vo_key(UAV), PoseEstimate(**pose, covariance=np.eye(6) * 0.01, source="vo")),
        (keys.pose_pf_key(UAV), PoseEstimate(**pose, covariance=np.eye(6) * 0.02, source="pf")),
        (keys.truth_key(UAV), PoseEstimate(**pose, covariance=np.zeros((6, 6)), source="truth")),
        (
            keys.stats_key("master", "m", 0),
            Stats(
                role="master",
                node="m",
                index=0,
                stamp_s=time.time(),
                uptime_s=1.0,
                timings_ms={"frame": 3.2},
                shares={"worker/h1/0": 1.0},
            ),
        ),
    ]


def _protobuf_decoder(schema_name: str, schema_b64: str) -> Any:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for fd in files.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name)).FromString


def _subscribe(ws: Any, channel_ids: list[int]) -> None:
    subscriptions = [{"id": i, "channelId": i} for i in channel_ids]  # subscription id = channel id
    ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))


def test_foxglove_client_receives_every_advertised_channel(tmp_path: Path, endpoint: str) -> None:
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    flight = hover_flight(seed=0, n_frames=3)
    service = ViewService(
        "view",
        0,
        peer(endpoint),
        ViewSettings(port=0, image_rate_hz=20.0),
    )
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    assert service.started.wait(20.0)
    done = threading.Event()

    def publish() -> None:
        with open_session(peer(endpoint)) as session:
            k = 0
            while not done.wait(0.1):
                for key, message in _messages(k, flight):
                    payload, attachment = encode(message)
                    session.put(key, payload, attachment=attachment)
                k += 1

    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
    channels: dict[int, dict[str, Any]] = {}
    retries = 0
    decoded: dict[str, Any] = {}
    try:
        with connect(
            f"ws://127.0.0.1:{service.port}",
            subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
            open_timeout=10,
        ) as ws:
            deadline = time.monotonic() + 60.0
            expected = {
                f"/capataz/uav/{UAV}/{t}"
                for t in (
                    "camera",
                    "yaw",
                    "cluster",
                    "attitude",
                    "pose/vo",
                    "pose/pf",
                    "truth",
                    "pose/vo/in_frame",
                    "pose/pf/in_frame",
                    "truth/in_frame",
                )
            }
            expected |= {"/tf", "/capataz/stats/master/m/0"}
            while time.monotonic() < deadline:
                advertised = {c["topic"] for c in channels.values()}
                if expected <= advertised and advertised <= set(decoded):
                    break
                try:
                    frame = ws.recv(timeout=1.0)
                except TimeoutError:
                    continue
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "advertise":
                        new = [c for c in op["channels"] if c["id"] not in channels]
                        for c in new:
                            channels[c["id"]] = c
                        _subscribe(ws, [c["id"] for c in new])
                    elif op["op"] == "status" and op["message"].startswith("Unknown channel ID"):
                        # foxglove-sdk 0.30 can advertise a channel a moment before it accepts subscriptions
                        # to it (seen 1 run in 2): subscribe again, as a client that keeps its view complete
                        retries += 1
                        time.sleep(0.1)
                        _subscribe(ws, [int(op["message"].rsplit(":", 1)[1])])
                    continue
                assert frame[0] == 1, frame[:1]  # MessageData
                sub_id, _t = struct.unpack_from("<IQ", frame, 1)
                c = channels[sub_id]
                payload = frame[13:]
                if c["topic"] in decoded:
                    continue  # one decoded message per channel is what is checked
                if c["encoding"] == "json":
                    decoded[c["topic"]] = json.loads(payload)
                else:
                    assert c["encoding"] == "protobuf" and c["schemaEncoding"] == "protobuf"
                    decoded[c["topic"]] = _protobuf_decoder(c["schemaName"], c["schema"])(payload)
    except ConnectionClosed as exc:  # pragma: no cover - a failure to report, not a path
        pytest.fail(f"server closed the connection: {exc}")
    finally:
        done.set()
        publisher.join(10.0)
        service.request_stop()
        runner.join(10.0)
    advertised = {c["topic"] for c in channels.values()}
    assert expected <= advertised, sorted(expected - advertised)
    assert advertised <= set(decoded), sorted(advertised - set(decoded))
    image = decoded[f"/capataz/uav/{UAV}/camera"]
    assert (image.width, image.height, image.encoding) == (376, 240, "mono8") and len(image.data) == 376 * 240
    assert decoded[f"/capataz/uav/{UAV}/yaw"]["yaw_rad"] == 0.25
    assert decoded[f"/capataz/uav/{UAV}/cluster"]["members"] == {"worker/h1/0": 40}
    assert np.allclose(decoded[f"/capataz/uav/{UAV}/pose/pf"]["covariance"], np.eye(6) * 0.02)
    pose = decoded[f"/capataz/uav/{UAV}/pose/pf/in_frame"]
    assert pose.frame_id == "world" and (pose.pose.position.x, pose.pose.position.z) == (1.0, 3.0)
    assert decoded["/tf"].parent_frame_id == "world"
    assert decoded["/capataz/stats/master/m/0"]["shares"] == {"worker/h1/0": 1.0}
    assert not runner.is_alive()
    assert retries <= len(advertised)


def test_deploy_layout_is_the_generated_one_and_names_only_served_topics() -> None:
    from services.tools.view.layout import layout_json, layout_topics

    path = Path(__file__).resolve().parents[3] / "deploy" / "foxglove" / "capataz.json"
    assert path.read_text() == layout_json("uav0"), "regenerate: capataz view --write-layout " + str(path)
    served = {f"/capataz/uav/uav0/{t}" for t in ("camera", "yaw", "cluster", "attitude", "pose/vo", "pose/pf",
              "truth", "pose/vo/in_frame", "pose/pf/in_frame", "truth/in_frame")}  # fmt: skip
    topics = layout_topics(json.loads(path.read_text()))
    assert topics and topics <= served, topics - served


@pytest.mark.parametrize("offered", [["foxglove.websocket.v1"], ["foxglove.sdk.v1"]])
def test_a_client_offering_either_name_of_the_protocol_is_served_regression(
    endpoint: str, offered: list[str]
) -> None:
    """Issue 28: a client offering only ``foxglove.websocket.v1`` (the protocol's name before foxglove-sdk;
    Lichtblick, older Foxglove apps) got HTTP 400. It is answered under the name it offered."""
    from websockets.sync.client import connect

    service = ViewService("view", 0, peer(endpoint), ViewSettings(port=0))
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    try:
        assert service.started.wait(20.0)
        with connect(f"ws://127.0.0.1:{service.port}", subprotocols=offered, open_timeout=10) as ws:
            assert ws.subprotocol == offered[0]
            hello = json.loads(ws.recv(timeout=10.0))
        assert hello["op"] == "serverInfo" and hello["name"] == "capataz"
    finally:
        service.request_stop()
        runner.join(10.0)


def test_only_the_old_name_alone_is_renamed_both_ways() -> None:
    from services.tools.view.subprotocol import rename_answer, rename_offer

    request = b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n"
    renamed, legacy = rename_offer(request)
    assert legacy and b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n" in renamed
    both = b"GET / HTTP/1.1\r\nsec-websocket-protocol: foxglove.sdk.v1, foxglove.websocket.v1\r\n\r\n"
    assert rename_offer(both) == (both, False)
    answer = b"HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    assert rename_answer(answer) == answer.replace(b"foxglove.sdk.v1", b"foxglove.websocket.v1")
