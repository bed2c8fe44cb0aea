"""The tf2_msgs package built from the extra's rosidl generators (services/ros2/tf2_msgs_build.py): in place
and current, ROS 2's own type (same type hash), and TFMessages go through its compiled Fast DDS type support
and come back equal. The bridge's end-to-end test receives it across processes on /tf_static."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.ros2 import extra_installed
from services.ros2.tf2_msgs_build import ROS_TYPE_HASH, build_key, default_layout, installed

NEEDS_EXTRA = pytest.mark.skipif(not extra_installed(), reason="ros2 extra not installed")
pytestmark = [pytest.mark.ros2, NEEDS_EXTRA]
ROOT = Path(__file__).resolve().parents[3]

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
frame_ids = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_/", max_size=20)
transforms = st.tuples(
    frame_ids, frame_ids, st.lists(finite, min_size=7, max_size=7), st.integers(0, 2**31 - 1)
)


def test_the_package_is_built_for_these_wheels() -> None:
    layout = default_layout()
    assert installed(layout), "tf2_msgs not built: make .venv/.installed"
    assert layout.stamp.read_text().strip() == build_key()


def test_the_type_is_ros_2s_own_tf_message() -> None:
    description = json.loads((default_layout().share / "tf2_msgs" / "msg" / "TFMessage.json").read_text())
    hashes = {h["type_name"]: h["hash_string"] for h in description["type_hashes"]}
    assert hashes["tf2_msgs/msg/TFMessage"] == ROS_TYPE_HASH
    fields = description["type_description_msg"]["type_description"]["fields"]
    assert [(f["name"], f["type"]["nested_type_name"]) for f in fields] == [
        ("transforms", "geometry_msgs/msg/TransformStamped")
    ]


@settings(max_examples=30, deadline=None)
@given(st.lists(transforms, max_size=6))
def test_tf_messages_survive_the_compiled_fast_dds_type_support(items: list) -> None:
    from geometry_msgs.msg import TransformStamped
    from rclpy.serialization import deserialize_message, serialize_message
    from tf2_msgs.msg import TFMessage

    message = TFMessage()
    for parent, child, values, sec in items:
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id, t.header.stamp.sec = parent, child, sec
        tr, q = t.transform.translation, t.transform.rotation
        tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w = values
        message.transforms.append(t)
    data = serialize_message(message)
    # CDR little endian: the encapsulation header, then the sequence's length
    assert data[:2] == b"\x00\x01" and struct.unpack("<I", data[4:8])[0] == len(items)
    assert deserialize_message(data, TFMessage) == message


def test_the_build_without_a_compiler_says_so_in_one_line(tmp_path: Path) -> None:
    env = {**os.environ, "PATH": str(tmp_path)}  # no cc, no c++
    result = subprocess.run(
        [sys.executable, "-m", "services.ros2.tf2_msgs_build", "--force", "--work", str(tmp_path / "w")],
        capture_output=True, text=True, cwd=ROOT, env=env, timeout=60,
    )  # fmt: skip
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == [
        "tf2_msgs build: no cc on PATH: the tf2_msgs build needs a C and a C++ compiler"
    ]
    assert installed(default_layout()), "a failed build removed the installed package"


def test_capataz_ros2_builds_it_once() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "services.tools.cli", "ros2", "--build-tf2-msgs"],
        capture_output=True, text=True, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("tf2_msgs already installed in ")
