"""Faulty captures (lip_ros.rig.faults): each fault does what it says inside its window and nothing outside it,
deterministically, and the windows it reports are on the sensors' clock."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from helpers import DEMO_BAG

from lip_msgs_py import MalformedMessageError, cloud_to_array, stamp_to_ns
from lip_ros.bagio import bag_span, read_messages, read_raw
from lip_ros.lip.sensors import IMU_TOPICS, LIDAR_TOPIC
from lip_ros.rig.faults import FAULT_KINDS, FaultSpec, read_fault_windows, write_faulty_bag

IMUS = sorted(IMU_TOPICS.values())
#: disjoint windows (s of receive time) of the faults that change messages one by one
WINDOWS = {"imu_silent": (1.0, 1.0), "imus_silent": (2.0, 0.5), "lidar_gap": (3.0, 0.5), "lidar_drops": (3.5, 5.0),
           "bad_imu_samples": (9.0, 0.5), "imu_reordered": (9.5, 0.5), "imu_ahead": (10.0, 0.5),
           "imu_late": (10.5, 0.5), "malformed_clouds": (11.0, 0.5), "blinded_clouds": (11.5, 0.5),
           "empty_clouds": (12.0, 0.3)}


def _by_topic(bag: Path) -> dict[str, list]:
    out = defaultdict(list)
    for m in read_messages(bag):
        out[m.topic].append(m)
    return out


def _inside(m, t0: int, kind: str) -> bool:
    start, seconds = WINDOWS[kind]
    return start <= (m.log_ns - t0) * 1e-9 < start + seconds


@pytest.fixture(scope="module")
def faulty(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, list], dict[str, list], int]:
    bag = tmp_path_factory.mktemp("faults") / "faulty"
    write_faulty_bag(DEMO_BAG, bag, [FaultSpec(k, *w) for k, w in WINDOWS.items()], seed=3)
    return bag, _by_topic(DEMO_BAG), _by_topic(bag), bag_span(DEMO_BAG)[0]


def test_silences_and_drops(faulty) -> None:
    bag, src, out, t0 = faulty
    assert not [m for m in out[IMUS[0]] if _inside(m, t0, "imu_silent")]
    assert [m for m in out[IMUS[1]] if _inside(m, t0, "imu_silent")]  # only the first IMU
    assert not [m for t in IMUS for m in out[t] if _inside(m, t0, "imus_silent")]
    assert not [m for m in out[LIDAR_TOPIC] if _inside(m, t0, "lidar_gap")]
    kept = sum(_inside(m, t0, "lidar_drops") for m in out[LIDAR_TOPIC])
    assert 40 <= kept < sum(_inside(m, t0, "lidar_drops") for m in src[LIDAR_TOPIC])  # 50 frames, about 10 % lost
    assert len(out["/gt/root_pose"]) == len(src["/gt/root_pose"])  # the truth is never touched


def test_bad_samples_reordering_and_late_imus(faulty) -> None:
    bag, src, out, t0 = faulty
    bad = [m for t in IMUS for m in out[t] if _inside(m, t0, "bad_imu_samples")]
    orientation = np.array([[m.msg.orientation.x, m.msg.orientation.y, m.msg.orientation.z, m.msg.orientation.w]
                            for m in bad])
    assert np.isnan(orientation).any() and (np.abs(orientation).sum(axis=1) == 0).any()
    assert np.isinf([m.msg.linear_acceleration.z for m in bad]).any()
    assert np.isnan([m.msg.angular_velocity.y for m in bad]).any()
    for topic in IMUS:
        stamps = [stamp_to_ns(m.msg.header.stamp) for m in out[topic] if _inside(m, t0, "imu_reordered")]
        assert np.any(np.diff(stamps) < 0) and np.any(np.diff(stamps) == 0)  # swapped, and some twice
        late = [m.log_ns - stamp_to_ns(m.msg.header.stamp) for m in out[topic]
                if WINDOWS["imu_late"][0] + 0.31 <= (m.log_ns - t0) * 1e-9 < sum(WINDOWS["imu_late"])]
        assert late and min(late) >= 300_000_000
    stamp = {m.log_ns: stamp_to_ns(m.msg.header.stamp) for m in src[IMUS[0]]}
    shift = {stamp_to_ns(m.msg.header.stamp) - stamp[m.log_ns] for m in out[IMUS[0]]
             if _inside(m, t0, "imu_ahead") and m.log_ns in stamp}  # not the reordered one held back into it
    assert shift == {40_000_000}


def test_malformed_blinded_and_empty_clouds(faulty) -> None:
    bag, src, out, t0 = faulty
    malformed = [m.msg for m in out[LIDAR_TOPIC] if _inside(m, t0, "malformed_clouds")]
    assert len(malformed) == 5
    for msg in malformed:
        with pytest.raises(MalformedMessageError):
            cloud_to_array(msg, ["x", "y", "z"])
    blinded = [cloud_to_array(m.msg) for m in out[LIDAR_TOPIC] if _inside(m, t0, "blinded_clouds")]
    assert len(blinded) == 5 and all((b["range"] == 0).all() and (b["x"] == 0).all() for b in blinded)
    empty = [m.msg for m in out[LIDAR_TOPIC] if _inside(m, t0, "empty_clouds")]
    assert len(empty) == 3 and all(m.width == m.height == len(m.data) == 0 for m in empty)


def test_windows_are_on_the_sensors_clock_and_the_bag_is_deterministic(faulty, tmp_path) -> None:
    bag, src, out, t0 = faulty
    windows = {w.kind: w for w in read_fault_windows(bag)}
    assert set(windows) == set(WINDOWS) and all(windows[k].description.startswith(FAULT_KINDS[k]) for k in windows)
    gap = windows["lidar_gap"]
    frames = [stamp_to_ns(m.msg.header.stamp) for m in src[LIDAR_TOPIC] if _inside(m, t0, "lidar_gap")]
    assert gap.start_ns <= min(frames) and max(frames) <= gap.end_ns
    again = tmp_path / "again"
    write_faulty_bag(DEMO_BAG, again, [FaultSpec(k, *w) for k, w in WINDOWS.items()], seed=3)
    assert all(a == b for a, b in zip(read_raw(again), read_raw(bag), strict=True))


def test_clock_steps_move_every_stamp_and_not_the_receive_times(tmp_path) -> None:
    bag = tmp_path / "clock"
    (window,) = write_faulty_bag(DEMO_BAG, bag, [FaultSpec("clock_back", 7.0, 100.0)])
    src, out, t0 = _by_topic(DEMO_BAG), _by_topic(bag), bag_span(DEMO_BAG)[0]
    for topic in (LIDAR_TOPIC, IMUS[0], "/gt/root_pose"):
        shift = np.array([stamp_to_ns(a.msg.header.stamp) - stamp_to_ns(b.msg.header.stamp)
                          for a, b in zip(out[topic], src[topic], strict=True)])
        after = np.array([(b.log_ns - t0) * 1e-9 >= 7.0 for b in src[topic]])
        assert (shift[after] == -5_000_000_000).all() and (shift[~after] == 0).all()
        assert [m.log_ns for m in out[topic]] == [m.log_ns for m in src[topic]]
    assert window.kind == "clock_back" and window.end_ns < max(stamp_to_ns(m.msg.header.stamp)
                                                               for m in src[LIDAR_TOPIC])
    with pytest.raises(ValueError, match="unknown fault"):
        FaultSpec("gremlins", 0.0, 1.0)


def test_a_capture_played_again_starts_over_with_its_own_stamps(tmp_path) -> None:
    bag = tmp_path / "again"
    (window,) = write_faulty_bag(DEMO_BAG, bag, [FaultSpec("played_again", 7.0, 5.0)])
    src, out, t0 = _by_topic(DEMO_BAG), _by_topic(bag), bag_span(DEMO_BAG)[0]
    for topic in (LIDAR_TOPIC, IMUS[0], "/gt/root_pose"):
        before = [m for m in src[topic] if m.log_ns - t0 < 7e9]
        again = [m for m in src[topic] if m.log_ns - t0 < 5e9]
        assert len(out[topic]) == len(before) + len(again)
        assert [m.log_ns for m in out[topic]] == [m.log_ns for m in before] + [m.log_ns + 7_000_000_000 for m in again]
        stamps = [stamp_to_ns(m.msg.header.stamp) for m in out[topic]]
        assert stamps == [stamp_to_ns(m.msg.header.stamp) for m in before + again]  # the capture's own stamps
    first = [stamp_to_ns(m.msg.header.stamp) for m in src[LIDAR_TOPIC] if m.log_ns - t0 < 5e9]
    assert window.kind == "played_again" and window.start_ns <= min(first) and max(first) <= window.end_ns


def test_a_fault_of_one_imu_hits_the_imu_named(tmp_path) -> None:
    """``FaultSpec.imu``: the named DOT goes silent, the others (the first by name among them) do not; an IMU the bag
    lacks, or a name on a fault of every IMU, is refused."""
    bag = tmp_path / "wrist"
    (window,) = write_faulty_bag(DEMO_BAG, bag, [FaultSpec("imu_silent", 3.0, 1.0, IMUS[-1])])
    out, t0 = _by_topic(bag), bag_span(DEMO_BAG)[0]
    inside = {topic: [m for m in out[topic] if 3.0 <= (m.log_ns - t0) * 1e-9 < 4.0] for topic in IMUS}
    assert not inside[IMUS[-1]] and all(inside[topic] for topic in IMUS[:-1])
    assert window.description.endswith(f"({IMUS[-1]})")
    with pytest.raises(ValueError, match="is not an IMU topic"):
        write_faulty_bag(DEMO_BAG, tmp_path / "none", [FaultSpec("imu_silent", 3.0, 1.0, "/dot/tail/imu")])
    with pytest.raises(ValueError, match="hit one IMU"):
        FaultSpec("imus_silent", 3.0, 1.0, IMUS[0])
