"""The shipped Fast DDS profile: chosen by default, never over the user's choice, loopback-neutral; message-sized
blocks reused by malloc."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from lip_ros.middleware import (
    PROFILE_ENV,
    PROFILE_FILE,
    keep_message_buffers,
    remove_stale_shm,
    use_lip_dds_profile,
)
from lip_ros.nodes import base
from lip_ros.resources import params_path
from lip_ros.tools import ros_cli

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


#: A fresh interpreter (transparent huge pages off, so that a fault is a page) allocates three 12.6 MB blocks at
#: once (a 2048-column cloud taken from DDS into Python), writes to every page and frees them, eleven rounds on
#: its main thread, then eleven on a thread of its own (another malloc arena), with or without
#: :func:`keep_message_buffers` first; it prints the page faults a round of the last ten of each, and the pages of
#: a round.
_FAULTS_SCRIPT = """
import ctypes, os, sys, threading
from lip_ros.middleware import keep_message_buffers
ctypes.CDLL(None).prctl(41, 1, 0, 0, 0)  # PR_SET_THP_DISABLE
if sys.argv[1] == "keep":
    assert keep_message_buffers()
page = os.sysconf("SC_PAGESIZE")
def faults():
    return int(open("/proc/self/stat").read().rsplit(")", 1)[1].split()[7])
def round_of_clouds(n=12_600_000):
    blocks = [bytearray(n) for _ in range(3)]
    for b in blocks:
        b[::page] = b"\\x01" * len(range(0, n, page))
def rounds(out):
    round_of_clouds()
    before = faults()
    for _ in range(10):
        round_of_clouds()
    out.append((faults() - before) / 10)
per_round = []
rounds(per_round)
thread = threading.Thread(target=rounds, args=(per_round,))
thread.start()
thread.join()
print(*per_round, 3 * -(-12_600_000 // page))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
                    reason="mallopt and the page-fault count of /proc/self/stat exist only with glibc on Linux")
def test_message_sized_blocks_are_reused_not_faulted_in_again() -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}

    def faults_per_round(mode: str) -> tuple[float, float, int]:
        run = subprocess.run([sys.executable, "-c", _FAULTS_SCRIPT, mode], env=env, capture_output=True, text=True,
                             timeout=60)
        assert run.returncode == 0, run.stderr
        main, thread, pages = run.stdout.split()
        return float(main), float(thread), int(pages)

    main, thread, pages = faults_per_round("default")
    assert main > 0.9 * pages and thread > 0.9 * pages  # glibc's defaults: every round maps and zeroes them again
    main, thread, _ = faults_per_round("keep")
    assert main < 0.01 * pages and thread < 0.01 * pages


def test_the_executables_keep_message_buffers_before_anything_else(monkeypatch) -> None:
    class Kept(Exception):
        pass

    def kept() -> bool:
        raise Kept

    def too_late(*_args: object) -> None:
        raise AssertionError("called before keep_message_buffers")

    monkeypatch.setattr(base, "keep_message_buffers", kept)
    monkeypatch.setattr(ros_cli, "keep_message_buffers", kept)
    for module, name in ((base, "stop_on_signals"), (base, "use_lip_dds_profile"), (ros_cli, "use_lip_dds_profile")):
        monkeypatch.setattr(module, name, too_late)
    with pytest.raises(Kept):  # before its signal handlers, the DDS profile and rclpy.init
        base.run_nodes("lip_test", "a test", [], [], ["lip_test"])
    with pytest.raises(Kept):
        ros_cli.start_ros(["lip_test"])


def test_malloc_options_the_user_set_are_left_alone() -> None:
    for env in ({"MALLOC_TRIM_THRESHOLD_": "1000000"}, {"MALLOC_MMAP_THRESHOLD_": "65536"}, {"MALLOC_TOP_PAD_": "0"},
                {"GLIBC_TUNABLES": "glibc.malloc.arena_max=2:glibc.malloc.trim_threshold=1000000"}):
        assert keep_message_buffers(env) is False
    assert keep_message_buffers({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2", "MALLOC_ARENA_MAX": "2"}) is True
