"""The DDS middleware kept on this machine: a Fast DDS profile with the loopback interface only, unicast
discovery, no multicast, and the environment that makes ``rmw_fastrtps_cpp`` load it.

The profile (:data:`LOOPBACK_PROFILE_XML`): one UDPv4 transport whose interface whitelist is ``127.0.0.1``,
the built-in transports off (no shared memory, no UDP on other interfaces), discovery to the initial peer
``127.0.0.1`` (unicast: with the metatraffic unicast locator set and no multicast locator, Fast DDS opens no
multicast socket), user data on ``127.0.0.1``. ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT`` tells
``rmw_fastrtps`` to leave the profile's discovery as it is (``LOCALHOST`` would have it add its own).
Every process of a ROS 2 graph that talks to the bridge needs the same environment (:func:`dds_environment`)
and the same ``ROS_DOMAIN_ID``; tests draw a random domain per run.
"""

from __future__ import annotations

import os
import random
from collections.abc import Mapping
from pathlib import Path

#: the only address the middleware uses
LOOPBACK = "127.0.0.1"
#: socket buffers (bytes): a 752x480 mono8 frame is 361 kB in ~6 UDP fragments of 64 kB
SOCKET_BUFFER_BYTES = 4 * 1024 * 1024

LOOPBACK_PROFILE_XML = f"""<?xml version="1.0" encoding="UTF-8" ?>
<!-- capataz: Fast DDS kept on this machine (loopback only, unicast discovery, multicast off) -->
<dds xmlns="http://www.eprosima.com">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>capataz_loopback</transport_id>
        <type>UDPv4</type>
        <interfaceWhiteList>
          <address>{LOOPBACK}</address>
        </interfaceWhiteList>
        <sendBufferSize>{SOCKET_BUFFER_BYTES}</sendBufferSize>
        <receiveBufferSize>{SOCKET_BUFFER_BYTES}</receiveBufferSize>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="capataz_loopback" is_default_profile="true">
      <rtps>
        <useBuiltinTransports>false</useBuiltinTransports>
        <userTransports>
          <transport_id>capataz_loopback</transport_id>
        </userTransports>
        <builtin>
          <metatrafficUnicastLocatorList>
            <locator><udpv4><address>{LOOPBACK}</address></udpv4></locator>
          </metatrafficUnicastLocatorList>
          <initialPeersList>
            <locator><udpv4><address>{LOOPBACK}</address></udpv4></locator>
          </initialPeersList>
        </builtin>
        <defaultUnicastLocatorList>
          <locator><udpv4><address>{LOOPBACK}</address></udpv4></locator>
        </defaultUnicastLocatorList>
      </rtps>
    </participant>
  </profiles>
</dds>
"""

#: where ``capataz ros2`` writes the profile when none is given (ignored ``out/``)
DEFAULT_PROFILE_PATH = Path("out/ros2/fastdds_loopback.xml")
#: DDS domain ids whose UDP ports stay below 65536 (7400 + 250 * id + offsets)
MAX_DOMAIN_ID = 232


def write_profile(path: Path) -> Path:
    """Write the loopback profile to ``path`` (folders created); returns the absolute path."""
    path = path.resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != LOOPBACK_PROFILE_XML:
        path.write_text(LOOPBACK_PROFILE_XML)
    return path


def profile_for(path: Path | None) -> Path:
    """The profile the bridge loads: a user's own file as it is; else the loopback profile, written to
    ``path`` (or :data:`DEFAULT_PROFILE_PATH`)."""
    if path is not None and path.is_file():
        return path.resolve()
    return write_profile(path or DEFAULT_PROFILE_PATH)


def dds_environment(profile: Path, domain_id: int) -> dict[str, str]:
    """The environment of every process of the graph: Fast DDS with ``profile``, in ``domain_id``."""
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"ROS domain id must be in 0..{MAX_DOMAIN_ID}, got {domain_id}")
    return {
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "FASTDDS_DEFAULT_PROFILES_FILE": str(profile),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
        "ROS_DOMAIN_ID": str(domain_id),
    }


def apply_environment(env: Mapping[str, str]) -> None:
    """Set ``env`` in this process (before ``rclpy.init``: the middleware reads it at start)."""
    os.environ.update(env)


def random_domain_id(rng: random.Random | None = None) -> int:
    """A random domain (1..MAX_DOMAIN_ID) to isolate one test run's graph from any other on the host."""
    return (rng or random.SystemRandom()).randint(1, MAX_DOMAIN_ID)


def udp_sockets_of(pid: int | str = "self") -> list[tuple[str, int]]:
    """``(address, port)`` of every UDP socket (IPv4 and IPv6) a process has open (Linux ``/proc``)."""
    inodes = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found: list[tuple[str, int]] = []
    for table, width in (("udp", 8), ("udp6", 32)):
        try:
            lines = Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if fields[9] not in inodes:
                continue
            hex_address, hex_port = fields[1].split(":")
            found.append((_address(hex_address, width), int(hex_port, 16)))
    return found


def _address(hex_address: str, width: int) -> str:
    raw = bytes.fromhex(hex_address)
    if width == 8:
        return ".".join(str(b) for b in reversed(raw))
    words = [raw[i : i + 4][::-1] for i in range(0, 16, 4)]
    return ":".join(b"".join(words)[i : i + 2].hex() for i in range(0, 16, 2))
