"""The shipped Fast DDS profile: chosen by default, never over the user's choice, loopback-neutral."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from lip_ros.middleware import PROFILE_ENV, PROFILE_FILE, remove_stale_shm, use_lip_dds_profile
from lip_ros.resources import params_path

NS = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_profile_is_set_when_the_user_chose_none() -> None:
    env: dict[str, str] = {}
    profile = use_lip_dds_profile(env)
    assert profile is not None and profile.is_file() and profile.name == PROFILE_FILE
    assert env == {PROFILE_ENV: str(profile)}


def test_the_users_profile_wins() -> None:
    for name in (PROFILE_ENV, "FASTDDS_DEFAULT_PROFILES_FILE"):
        env = {name: "/etc/my_dds.xml"}
        assert use_lip_dds_profile(env) is None
        assert env == {name: "/etc/my_dds.xml"}


def test_an_empty_variable_opts_out() -> None:
    env = {PROFILE_ENV: ""}
    assert use_lip_dds_profile(env) is None
    assert env == {}  # Fast DDS's defaults, without its parse error for an empty file name


def test_profile_enlarges_shared_memory_and_leaves_discovery_alone() -> None:
    root = ET.parse(params_path(PROFILE_FILE)).getroot()
    shm = [d for d in root.iterfind(".//p:transport_descriptor", NS) if d.findtext("p:type", namespaces=NS) == "SHM"]
    assert len(shm) == 1
    assert int(shm[0].findtext("p:segment_size", namespaces=NS)) >= 128 * 2**20
    participant = root.find(".//p:participant[@is_default_profile='true']", NS)
    transport_id = shm[0].findtext("p:transport_id", namespaces=NS)
    assert [t.text for t in participant.iterfind(".//p:userTransports/p:transport_id", NS)] == [transport_id]
    # no UDP settings, locators, peers or multicast: ROS_AUTOMATIC_DISCOVERY_RANGE and ROS_DOMAIN_ID rule discovery
    tags = {el.tag.split("}")[1] for el in root.iter()}
    assert not tags & {"domainId", "initialPeersList", "metatrafficMulticastLocatorList",
                       "metatrafficUnicastLocatorList", "defaultUnicastLocatorList", "defaultMulticastLocatorList",
                       "interfaceWhiteList", "locator"}
    assert all(d.findtext("p:type", namespaces=NS) == "SHM" for d in root.iterfind(".//p:transport_descriptor", NS))


def test_stale_shared_memory_is_removed_and_memory_in_use_is_not(tmp_path) -> None:
    """A segment whose lock file no one holds (its process was killed) goes, with its port semaphore; one held
    (a live participant) and one too new (being set up) stay."""
    import fcntl
    import os

    for name in ("fastrtps_dead", "fastrtps_live", "fastrtps_port7001", "fastrtps_new"):
        (tmp_path / name).write_bytes(b"x")
        (tmp_path / f"{name}_el").touch()
        os.utime(tmp_path / f"{name}_el", (1.0, 1.0))  # long ago
    (tmp_path / "sem.fastrtps_port7001_mutex").touch()
    (tmp_path / "fastrtps_new_el").touch()  # now
    held = os.open(tmp_path / "fastrtps_live_el", os.O_RDWR)
    fcntl.flock(held, fcntl.LOCK_EX)
    try:
        removed = remove_stale_shm(tmp_path, min_age_s=5.0)
    finally:
        os.close(held)
    assert sorted(p.name for p in removed) == ["fastrtps_dead", "fastrtps_dead_el", "fastrtps_port7001",
                                               "fastrtps_port7001_el", "sem.fastrtps_port7001_mutex"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fastrtps_live", "fastrtps_live_el", "fastrtps_new",
                                                          "fastrtps_new_el"]
