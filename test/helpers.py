"""Shared by the tests: the package's executables started as separate processes, the bundled demo bag, the online
calibration fed as data comes."""

from __future__ import annotations

import shutil
import sys
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEMO_BAG = REPO / "bags" / "demo_walk"
#: The HSC4D capture the node tests share (``hsc4d_run`` in test/nodes/conftest.py): seed 5's A-pose, its jump
#: landing at about 6 s, then walking; keyword arguments of ``SiteCaptureConfig``.
HSC4D_CAPTURE = {"seed": 5, "seconds": 20.0}
#: How the node tests play HSC4D captures through ``lip_process_bag``: paced by the graph's poses and by what its
#: LiDAR input has taken (before the jump no pose comes), at full speed. Paced by poses alone, on a machine twice as
#: slow as usual, the graph lost 2-21 of 200 clouds (76-119 of 280 at 20 Hz); paced by both, none (session 39),
#: but in the two-worker suite the capture played again lost its whole second pass, likely (not reproduced) as the
#: body node, held seconds by the first pass's last window, placed the new capture's first fused pose before it took
#: the suit's odometry that showed the new capture (it takes it first since session 40; sessions 39-40 played these
#: tests at half speed). What each sweep becomes is the tests' concern; how fast the graph is, the benchmarks'
#: (bench_hsc4d_graph.py).
HSC4D_PLAYBACK = ("--paced",)


#: The end of a Python script that a test runs as a ROS process (``python -c``): says "ready" and spins its
#: ``node`` until SIGINT.
SPIN_UNTIL_SIGINT = """
print("ready", flush=True)
try:
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.1)
except KeyboardInterrupt:
    pass
"""


def console_script(name: str) -> str:
    """Path of one of the package's console scripts in the running environment."""
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    assert exe, f"{name} console script not installed in this environment"
    return exe


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, ended and not reaped yet, does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def descendants(pid: int) -> list[int]:
    """The processes below ``pid`` (its children, theirs, ...), from /proc."""
    found, todo = [], [pid]
    while todo:
        for task in Path(f"/proc/{todo.pop()}/task").glob("*"):
            try:
                kids = [int(k) for k in (task / "children").read_text().split()]
            except OSError:
                continue
            found += kids
            todo += kids
    return found


def feed_detector(detector, streams: Mapping, clouds: Sequence[tuple[int, np.ndarray]], every_ns: int = 250_000_000
                  ) -> Iterator[int]:
    """Feed a :class:`~lip_ros.lip.calibration.CalibrationDetector` the rig's DOT streams and (stamp, points) clouds in
    stamp order, calling ``update`` every ``every_ns``; yields each stamp it was called at, until it calibrated."""
    events = sorted([(int(x.stamp_ns[k]), 0, n, k) for n, x in streams.items() for k in range(len(x.stamp_ns))]
                    + [(t, 1, "", i) for i, (t, _) in enumerate(clouds)])
    next_update = events[0][0]
    for stamp, kind, name, k in events:
        if kind == 0:
            x = streams[name]
            detector.add_imu(name, stamp, x.quat[k], x.gyro[k], x.accel[k])
        else:
            detector.add_cloud(stamp, clouds[k][1])
        if stamp >= next_update:
            next_update += every_ns
            yield stamp
            if detector.update() is not None:
                return


def assert_poses_match_the_batch_core(outputs: Path, bag: Path = DEMO_BAG) -> int:
    """The live graph's ``/lip/root_pose`` in ``outputs`` against ``bag`` through ``lip_ros.lip.batch.replay_bag`` (no
    DDS): the same frames posed (95 % in common) and the same poses (median below 0.1 mm); the poses compared."""
    from lip_msgs_py import msg_to_pose_stamped
    from lip_ros.bagio import read_messages
    from lip_ros.lip.batch import replay_bag
    from lip_ros.lip.nets.lip_model import LipModel
    from lip_ros.lip.pipeline import LipPipeline, Outcome
    from lip_ros.lip.sensors import LIP_TOPICS

    live = {p.stamp_ns: p for p in map(msg_to_pose_stamped,
                                       (m.msg for m in read_messages(outputs, [LIP_TOPICS.root_pose])))}
    batch = {r.pose.stamp_ns: r.pose for r in replay_bag(LipPipeline(LipModel.load()), bag)
             if r.outcome == Outcome.POSE}
    common = sorted(set(live) & set(batch))
    assert len(common) >= 0.95 * max(len(live), len(batch)), (len(live), len(batch), len(common))
    diff = np.array([np.linalg.norm(live[t].position - batch[t].root_pos) for t in common])
    assert np.median(diff) < 1e-4 and np.percentile(diff, 95) < 0.01, (np.median(diff), diff.max())
    return len(common)
