"""The DDS middleware stays on this machine: the Fast DDS profile the bridge and the tests use names the
loopback address only, turns the built-in transports (every interface, shared memory) off, discovers by
unicast to 127.0.0.1 and opens no multicast locator; the environment points rmw_fastrtps at it."""

from __future__ import annotations

import random
import socket
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from services.ros2.dds import (
    LOOPBACK,
    LOOPBACK_PROFILE_XML,
    MAX_DOMAIN_ID,
    dds_environment,
    profile_for,
    random_domain_id,
    udp_sockets_of,
    write_profile,
)

NS = {"d": "http://www.eprosima.com"}


def test_the_profile_names_no_address_but_loopback_and_no_multicast() -> None:
    root = ET.fromstring(LOOPBACK_PROFILE_XML)
    addresses = [a.text for a in root.iter("{http://www.eprosima.com}address")]
    assert addresses and set(addresses) == {LOOPBACK}
    transports = root.findall(".//d:transport_descriptor", NS)
    assert [t.findtext("d:type", namespaces=NS) for t in transports] == ["UDPv4"]
    whitelist = transports[0].findall("d:interfaceWhiteList/d:address", NS)
    assert [a.text for a in whitelist] == [LOOPBACK]
    participant = root.find(".//d:participant", NS)
    assert participant is not None and participant.get("is_default_profile") == "true"
    rtps = participant.find("d:rtps", NS)
    assert rtps is not None
    assert rtps.findtext("d:useBuiltinTransports", namespaces=NS) == "false"
    assert rtps.findtext("d:userTransports/d:transport_id", namespaces=NS) == transports[0].findtext(
        "d:transport_id", namespaces=NS
    )
    peers = rtps.findall("d:builtin/d:initialPeersList/d:locator/d:udpv4/d:address", NS)
    assert [p.text for p in peers] == [LOOPBACK]
    assert rtps.findall("d:builtin/d:metatrafficUnicastLocatorList/d:locator", NS)
    assert "ulticast" not in LOOPBACK_PROFILE_XML.replace("metatrafficUnicast", "").replace(
        "multicast off", ""
    )


def test_the_environment_selects_fast_dds_with_the_profile_and_leaves_its_discovery_alone(
    tmp_path: Path,
) -> None:
    profile = write_profile(tmp_path / "sub" / "p.xml")
    assert profile.read_text() == LOOPBACK_PROFILE_XML and profile.is_absolute()
    env = dds_environment(profile, 17)
    assert env["RMW_IMPLEMENTATION"] == "rmw_fastrtps_cpp"
    assert env["FASTDDS_DEFAULT_PROFILES_FILE"] == str(profile)
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" not in env  # deprecated name: rmw_fastrtps warns about it
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    assert env["ROS_DOMAIN_ID"] == "17"
    with pytest.raises(ValueError, match="domain"):
        dds_environment(profile, MAX_DOMAIN_ID + 1)


def test_a_users_own_profile_is_loaded_as_it_is_and_a_missing_one_is_the_loopback_profile(
    tmp_path: Path,
) -> None:
    own = tmp_path / "own.xml"
    own.write_text("<dds/>")
    assert profile_for(own) == own.resolve() and own.read_text() == "<dds/>"
    missing = tmp_path / "new" / "p.xml"
    assert profile_for(missing).read_text() == LOOPBACK_PROFILE_XML


def test_random_domains_stay_in_the_udp_port_range() -> None:
    rng = random.Random(3)
    ids = {random_domain_id(rng) for _ in range(2000)}
    assert min(ids) >= 1 and max(ids) <= MAX_DOMAIN_ID and len(ids) > 100
    assert 7400 + 250 * MAX_DOMAIN_ID + 10 + 2 * 20 < 65536  # PDP port of the 20th participant


def test_the_udp_sockets_of_a_process_are_read_from_proc() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        port = s.getsockname()[1]
        assert (LOOPBACK, port) in udp_sockets_of()
    assert (LOOPBACK, port) not in udp_sockets_of()
