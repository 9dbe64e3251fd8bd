"""The HSC4D graph over real DDS on faulty rig captures (lip_ros.rig.faults), through ``lip_process_bag``: the suit's
IMUs silent or late, LiDAR gaps and malformed clouds, both clocks stepping back 5 s and ahead again, and the capture
played again from its start (a bag loop). No process fails, every sweep is accounted for, and the trajectory stays
as accurate as on the clean capture: before the odometry bridged the suit's gaps it ended 3.1 m off after these
faults, after a clock step back the graph waited for another jump and published nothing more, and the capture
played again was tracked on from where the first pass ended, a metre off (docs/reliability.md, "The HSC4D
graph")."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import HSC4D_CAPTURE, HSC4D_PLAYBACK, console_script

from lip_msgs_py import msg_to_diagnostics, msg_to_odometry, msg_to_pose_array, msg_to_pose_stamped
from lip_ros.bagio import read_messages
from lip_ros.hsc4d.sensors import HSC4D_TOPICS, ODOMETRY_TOPIC, OPTIMISED_ODOMETRY_TOPIC
from lip_ros.rig.faults import FaultSpec, write_faulty_bag
from lip_ros.tools.process_bag import HSC4D, summarize_outputs

pytestmark = pytest.mark.ros  # DDS traffic and subprocesses

#: the faults of each run on the session's capture (``hsc4d_run``: 20 s, the jump landing at about 6 s; the
#: accuracy is aligned on the 5 s after it)
FAULTS = {
    "clean": [],
    # each of these alone took the trajectory metres off before (imus_silent 11 m, imu_late 1.3 m in 30 s)
    "sensors": [FaultSpec("imus_silent", 12.0, 1.0), FaultSpec("imu_late", 14.0, 1.0),
                FaultSpec("lidar_gap", 16.0, 1.0), FaultSpec("malformed_clouds", 17.5, 0.3)],
    # both clocks 5 s back at 12 s, and 5 s ahead again at 16 s
    "clock": [FaultSpec("clock_back", 12.0, 100.0), FaultSpec("clock_forward", 16.0, 100.0)],
    # at 14 s the capture starts again from its beginning (its own stamps) and plays whole
    "loop": [FaultSpec("played_again", 14.0, HSC4D_CAPTURE["seconds"])],
}
STEP_NS = 5_000_000_000


@pytest.fixture(scope="module")
def runs(hsc4d_run) -> dict[str, tuple[Path, Path, subprocess.CompletedProcess]]:
    """``lip_process_bag`` on the clean capture (the session's) and on each faulty copy: name -> (bag, outputs,
    process)."""
    capture = hsc4d_run[0]
    out = {"clean": hsc4d_run}
    for name, faults in FAULTS.items():  # paced: about a minute each, twice that on a slow machine
        if not faults:
            continue
        bag = capture.with_name(name)
        write_faulty_bag(capture, bag, faults, seed=5)
        outputs = capture.with_name(f"{name}_outputs")
        command = [console_script("lip_process_bag"), str(bag), str(outputs), *HSC4D_PLAYBACK]
        out[name] = bag, outputs, subprocess.run(command, capture_output=True, text=True, timeout=240)
    return out


def _poses(outputs: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (N,) and pelvis positions (N, 3) of /hsc4d/odometry in the order published."""
    odometry = [msg_to_odometry(m.msg) for m in read_messages(outputs, [ODOMETRY_TOPIC])]
    return np.array([o.stamp_ns for o in odometry]), np.array([o.position for o in odometry])


def _joints(outputs: Path, moment_of: dict[int, int] | None = None) -> dict[int, np.ndarray]:
    """/hsc4d/joint_poses: (24, 3) joint positions by the moment they hold (their stamp, or ``moment_of`` it); of
    the same moment twice, the last."""
    out = {}
    for m in read_messages(outputs, [HSC4D_TOPICS.joint_poses]):
        poses = msg_to_pose_array(m.msg)
        out[(moment_of or {}).get(poses.stamp_ns, poses.stamp_ns)] = poses.positions
    return out


def _assert_near_the_clean_run(moments: np.ndarray, positions: np.ndarray, joints: dict[int, np.ndarray],
                               clean_outputs: Path, median_m: float = 0.02, max_m: float = 0.10) -> None:
    """The pelvis at each moment (N,) where the clean run put it (median under ``median_m``, at most ``max_m``;
    kiss-icp on two threads is not repeatable to the bit), and the body's joints, about the pelvis, as the clean
    run's (the suit's samples matched at the same moments: 100 ms off would move a walker's hands and feet by
    several cm); all but
    6 of the clean run's poses and bodies among them."""
    clean = dict(zip(*(a.tolist() for a in _poses(clean_outputs))))
    common = [k for k, t in enumerate(moments) if int(t) in clean]
    assert len(common) >= len(clean) - 6, (len(common), len(clean))
    apart = np.linalg.norm(positions[common] - np.array([clean[int(moments[k])] for k in common]), axis=1)
    assert np.median(apart) < median_m and apart.max() < max_m, (np.median(apart), apart.max())
    clean_joints = _joints(clean_outputs)
    common = sorted(set(joints) & set(clean_joints))
    assert len(common) >= len(clean_joints) - 6, (len(common), len(clean_joints))
    relative = [np.linalg.norm((joints[t] - joints[t][0]) - (clean_joints[t] - clean_joints[t][0]), axis=1).mean()
                for t in common]
    assert np.median(relative) < 0.005 and max(relative) < 0.03, (np.median(relative), max(relative))


def _last_diagnostics(outputs: Path) -> dict[str, Any]:
    """Each status's last report on /diagnostics, by name."""
    last = {}
    for m in read_messages(outputs, ["/diagnostics"]):
        last.update((s.name, s) for s in msg_to_diagnostics(m.msg).statuses)
    return last


@pytest.mark.parametrize("name", list(FAULTS))
def test_no_process_fails_and_every_sweep_is_accounted_for(runs, name: str) -> None:
    bag, outputs, proc = runs[name]
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "terminate called" not in proc.stderr
    summary = summarize_outputs(bag, outputs, HSC4D)
    assert "not accounted for" not in proc.stdout, proc.stdout
    assert sum(summary.frames.values()) == summary.frames_in, summary.frames
    stamps, positions = _poses(outputs)
    assert np.isfinite(positions).all()
    # sensors: the faults' own frames; loop: the first pass's sweeps still queued when the new capture begins (5 of
    # them with another process busy on one of the two cores)
    lost = {"sensors": 40, "loop": 15}.get(name, 5)
    assert summary.frames["pose"] >= summary.frames_in - lost, summary.frames


def test_the_trajectory_bridges_the_sensors_faults(runs) -> None:
    """As accurate as on the clean capture: ATE within 2 cm of it and under 8 cm (clean: about 3 cm)."""
    clean = summarize_outputs(*runs["clean"][:2], HSC4D).hsc4d
    faulty = summarize_outputs(*runs["sensors"][:2], HSC4D).hsc4d
    assert faulty.ate_m < min(clean.ate_m + 0.02, 0.08), (clean.ate_m, faulty.ate_m)
    assert faulty.final_m < clean.final_m + 0.05, (clean.final_m, faulty.final_m)


def test_after_the_clocks_step_the_trajectory_goes_on_as_on_the_clean_capture(runs) -> None:
    """The outputs follow the LiDAR's clock (their stamps step back and ahead with it), resume with the next sweep,
    and, each taken back to the moment it holds, are where the clean run put the pelvis then."""
    stamps, positions = _poses(runs["clock"][1])
    steps = np.diff(stamps)
    back, ahead = np.flatnonzero(steps < -STEP_NS // 2), np.flatnonzero(steps > STEP_NS // 2)
    assert len(back) == 1 and len(ahead) == 1 and back[0] < ahead[0], steps[np.abs(steps) > 200_000_000]
    assert -STEP_NS + 100_000_000 <= steps[back[0]] <= -STEP_NS + 300_000_000  # the next sweep or the one after
    moment = stamps.copy()
    moment[back[0] + 1: ahead[0] + 1] += STEP_NS
    _assert_near_the_clean_run(moment, positions, _joints(runs["clock"][1], dict(zip(stamps.tolist(),
                                                                                     moment.tolist()))),
                               runs["clean"][1])
    last = _last_diagnostics(runs["clock"][1])
    assert last["hsc4d_trajectory_node: frames"].values["clock steps back (LiDAR, suit)"] == "1, 1"
    assert last["hsc4d_body_node: frames"].values["clock steps back (LiDAR, suit)"] == "1, 1"
    bodies = [msg_to_pose_stamped(m.msg).stamp_ns for m in read_messages(runs["clock"][1], [HSC4D_TOPICS.root_pose])]
    assert len(bodies) >= len(stamps) - 5  # the body goes on with the trajectory


def test_a_capture_played_again_is_tracked_again_from_its_jump(runs) -> None:
    """The capture played again from its start (a bag loop): both nodes see a new capture begin (the suit's pelvis
    jumps across its clock's step back), the trajectory waits for the new capture's jump and tracks it as the clean
    run did; the first pass too, and its last partial window is optimised once the new capture has begun. Before,
    the trajectory went on from where the first pass ended (96 cm off)."""
    bag, outputs, _ = runs["loop"]
    stamps, positions = _poses(outputs)
    back = np.flatnonzero(np.diff(stamps) < -STEP_NS)  # the capture is 14 s in when it starts again
    assert len(back) == 1, np.diff(stamps)[np.diff(stamps) < 0]
    first = np.arange(back[0] + 1)
    # all but the first pass's sweeps still queued when the new capture begins (skipped, counted: none without
    # load, 5 with another process busy on one of the two cores; docs/reliability.md). A whole make test in session
    # 41 posed 136 of the first pass (the four not told apart: queued then, or clouds lost in transport)
    assert stamps[first].max() < stamps[0] + 14 * 10**9 and len(first) >= 14 * 10 - 6, len(first)
    second = np.arange(back[0] + 1, len(stamps))
    everything = list(read_messages(outputs, [HSC4D_TOPICS.joint_poses]))
    poses = [msg_to_pose_array(m.msg) for m in everything]
    body_back = np.flatnonzero(np.diff([p.stamp_ns for p in poses]) < -STEP_NS)
    assert len(body_back) == 1
    joints = {p.stamp_ns: p.positions for p in poses[body_back[0] + 1:]}
    # the first pass's last frames in the optimiser when the new capture begins are solved with what there is (its
    # optimiser closing beside the new capture's): every body posed in the first pass gets its optimised pose
    optimised = np.array([msg_to_odometry(m.msg).stamp_ns for m in read_messages(outputs, [OPTIMISED_ODOMETRY_TOPIC])])
    optimised_back = np.flatnonzero(np.diff(optimised) < -STEP_NS)
    assert len(optimised_back) == 1
    first_bodies = [p.stamp_ns for p in poses[:body_back[0] + 1]]
    assert optimised[:optimised_back[0] + 1].tolist() == first_bodies
    # a new trajectory from the new capture's jump, as the clean run's: 0.00 cm (median and largest) when it gets
    # the same samples; 2.24 cm (at most 5.0) when the new capture's first pelvis sample comes before its first
    # odometry message and is refused as far behind (a clock step not confirmed yet; 1 of 2 runs without load, and
    # a make test, session 32). ROS-free, that one sample fewer moves this capture's trajectory by 0.9 cm (at most
    # 2.8; session 32's build 1.7 and 5.2, with the sweep's rotation from the suit's orientations 0.6 and 3.5), from
    # the jump on: the bound is session 32's spread, far under the 96 cm of a trajectory that went on from the
    # first pass (docs/reliability.md)
    _assert_near_the_clean_run(stamps[second], positions[second], joints, runs["clean"][1], median_m=0.04)
    clean = dict(zip(*(a.tolist() for a in _poses(runs["clean"][1]))))
    apart = np.linalg.norm(positions[first] - np.array([clean[int(t)] for t in stamps[first]]), axis=1)
    # the same samples as the clean run: 0.00 cm without load, 2.2 cm once in a make test (session 31)
    assert np.median(apart) < 0.04 and apart.max() < 0.10, (np.median(apart), apart.max())
    last = _last_diagnostics(outputs)
    for node in ("hsc4d_trajectory_node", "hsc4d_body_node"):
        assert last[f"{node}: frames"].values["new captures begun"] == "1"
    assert "pelvis jumped" in last["hsc4d_trajectory_node: frames"].values["last new capture"]
    waiting = [s for m in read_messages(outputs, ["/diagnostics"]) for s in msg_to_diagnostics(m.msg).statuses
               if s.name == "hsc4d_trajectory_node: frames" and s.values["new captures begun"] == "1"
               and s.values["suit clock offset (ms)"] == "unknown"]
    assert waiting and all(s.level == 1 and s.message.startswith("a new capture began") for s in waiting), waiting[:1]


def test_the_offline_refinement_of_a_capture_played_again_refines_the_first_pass(runs) -> None:
    """``lip_process_bag --refine``'s refinement (:func:`refine_bag`) stops where the capture begins again (the nodes'
    rule) and counts the sweeps after; before, the second pass's sweeps past the first's last stamp went on the
    first pass's trajectory."""
    from lip_ros.hsc4d.batch import LATER_CAPTURE, refine_bag  # torch

    bag = runs["loop"][0]
    _, refinement, skipped = refine_bag(bag)
    clean = _poses(runs["clean"][1])[0]
    first_pass = clean[clean < clean[0] + 14 * 10**9]
    assert refinement.stamps_ns.max() <= first_pass.max() and len(refinement.stamps_ns) >= len(first_pass) - 3
    assert skipped[LATER_CAPTURE] >= len(clean) - 3, skipped  # the second pass, whole but a sweep or two
