"""hsc4d_trajectory_node: the hip LiDAR's odometry fused with the suit, live (jump sync, kiss-icp, pose graph).

Takes the hip Ouster's clouds, the suit's pelvis IMU and the suit's own
odometry (each on its own clock) into a
:class:`lip_ros.hsc4d.trajectory.TrajectoryPipeline`. Until the performer's
jump is seen in both the LiDAR and the suit it holds the sweeps and publishes
nothing (``/diagnostics`` says what it waits for); then it publishes the suit's
clock offset (latched, for ``hsc4d_body_node``) and, for every sweep, the fused
pelvis pose on ``/hsc4d/odometry`` (nav_msgs/Odometry in ``map``: gravity
aligned, z up, origin on the ground under the first pelvis position; stamped
with the sweep's reference time on the LiDAR's clock; twist from the last
pose, in the pelvis frame) and, where tf2_msgs is installed, ``map`` ->
``pelvis`` on /tf. Each posed sweep's points then go into the map of the
whole site (:class:`lip_ros.hsc4d.site_map.SiteMap`, 0.1 m voxels, placed by
the live odometry), which goes out every ``map_period_s`` on ``/hsc4d/map``
(reliable, transient local).

The sweeps held until the jump are registered with each new sweep for at most
0.3 of a LiDAR period (``_CATCH_UP_SHARE``; not in one long callback, during which the suit's samples
would overflow their queues); a sweep waits (at most ``suit_wait_s`` after it arrived) until the
suit's samples cover it, so that its deskew and initial guess have the suit's
motion whatever order the transport delivers in (and the pelvis samples within
it, not only the newest: :meth:`TrajectoryPipeline.suit_covers`).

When the LiDAR's or the suit's clock steps back (a PTP step; stamps more than
0.5 s behind; for the suit, confirmed by its next message), the trajectory
goes on: each clock's stamps are moved on by the step
(:class:`lip_ros.core.clock.SteppingClock`; the suit's first message behind is
refused), the map, the offset and the mounting
are kept, and the outputs are stamped as the LiDAR's clock now reads. A step
ahead is a gap in the stamps, which the odometry bridges with the suit's
motion. A sweep not after the last one otherwise is skipped. When the suit's
pelvis jumps across its clock's step back (a bag played again, the suit's
driver restarted: :class:`lip_ros.hsc4d.suit_restart.SuitRestart`), a new
capture began: the sweeps of the last one are registered with what there is,
those it still held (and any that come late) are skipped and counted, and a
new trajectory (map, offset and mounting included) waits for the new
capture's jump; the sweeps of the new capture received so far go to it.

With ``resume_file`` the node writes its state every ``resume_period_s``
(:mod:`lip_ros.hsc4d.resume`) and, started again mid-capture (a crash), goes
on from it at the first sweep instead of waiting for a jump, if the state is
at most ``resume_max_gap_s`` older than that sweep (docs/hsc4d/graph.md).
"""

from __future__ import annotations

import time
from collections import Counter, deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile
from sensor_msgs.msg import Imu, PointCloud2
from std_msgs.msg import Int64

from lip_msgs_py import (
    DiagnosticLevel,
    MalformedMessageError,
    cloud_to_xyz_time,
    msg_to_imu,
    msg_to_odometry,
    odometry_to_msg,
    read_header,
    tf_message,
    transform_stamped_to_msg,
    xyz_to_cloud,
)
from lip_ros.core.clock import SteppingClock, stepped_back
from lip_ros.core.rotations import matrix_to_axis_angle, matrix_to_quat
from lip_ros.hsc4d.lidar_odometry import OdometryConfig
from lip_ros.hsc4d.mount import HipMountPrior
from lip_ros.hsc4d.resume import TrajectoryResume, load_resume, map_file, resume_refusal, save_resume
from lip_ros.hsc4d.suit_restart import SuitRestart
from lip_ros.hsc4d.trajectory import RESUME_WAITS, TrajectoryConfig, TrajectoryPipeline, TrajectoryStep
from lip_ros.nodes.base import (
    IMU_INPUT,
    LATCHED,
    POLL_PERIOD_S,
    SUIT_QUEUE_S,
    GraphNode,
    LatencyWindow,
    Param,
    ParameterError,
    non_negative,
    numbers,
    positive,
    run_nodes,
    suit_input,
    tf_publisher,
)
from lip_ros.nodes.hsc4d import (
    FUSED_ODOMETRY_QOS,
    HSC4D_PARAMS_FILE,
    MOUNT_HIP_VALUE,
    MOUNT_SPIN_VALUE,
    OFFSET_VALUE,
)

__all__ = ["TrajectoryNode", "main"]

#: the pipeline's counts of sweeps it dropped -> how this node accounts for those frames
_DROPPED = {"sweeps dropped waiting for the jump": "skipped: held too long (no jump)",
            "sweeps dropped waiting for the map frame": "skipped: held too long (no map frame)",
            "sweeps dropped: registration fell behind": "skipped: registration fell behind",
            RESUME_WAITS: "skipped: resumed, before the suit's data"}
_MAX_TWIST_DT_S = 0.5  # the twist is left zero across a longer gap between outputs
#: the cloud input keeps this much of clouds (SensorDataQoS otherwise): the longest callback (registering a few
#: sweeps while the rest of the process also wants the interpreter) measured up to about a second, and while the
#: backlog after the jump is worked off at 20 Hz the node runs up to a second behind (a queue of 20 clouds lost
#: 33-46 of 600 there)
_CLOUD_QUEUE_S = 2.0
#: with each sweep taken, two of the sweeps waiting are registered (the oldest first, the new one behind them; one
#: in steady state), so the backlog left by the jump shrinks by one a sweep at least, and more while the whole
#: call stays within this share of a LiDAR period: the rest is the process's other work (at 20 Hz, 0.5 of the
#: period lost clouds in DDS, 33 of 600, while the backlog was worked off; docs/hsc4d/graph.md)
_CATCH_UP_SHARE = 0.3
#: The input names of the suit's topics, in the order they are subscribed and taken: the odometry first, so that
#: of a backlog the new capture's first odometry message (a bag played again: :class:`SuitRestart`) starts the new
#: trajectory before its pelvis samples come in; taken after them, those went on the last capture's time line and
#: the new trajectory lost its first ones (under load, 4.9 cm off where 0.6-1.0 cm without).
_SUIT_INPUTS = ("suit odometry", "suit pelvis imu")
_LIDAR = "hip lidar"  # the LiDAR's input name
_MAX_TRACKED = 1000  # sweeps whose receipt time is kept for the latency
#: how a sweep of the last capture is accounted for when a new one began (held by the trajectory, or come late)
_BEGAN_AGAIN = "skipped: a new capture began"
#: a saved state is not resumed from when the suit's newest odometry is farther than this from where the saved clock
#: offset puts the first sweep (its samples come within a queue's length of the LiDAR's)
_RESUME_SUIT_SLACK_S = 2.0


@dataclass(frozen=True)
class _Sweep:
    stamp_ns: int
    points: np.ndarray
    point_ns: np.ndarray
    received: float  # monotonic s
    end_ns: int  # the time of its last point
    clock_ns: int  # its stamp as the LiDAR's clock read it (stamp_ns is on the node's time line)


def _mount_check(pipe: TrajectoryPipeline) -> str:
    """The hand-eye check of the levelled mounting, or how far the turns have got towards it."""
    deg = pipe.mount_disagreement_deg
    if deg is not None:
        return f"{deg:.2f}"
    turned = pipe.hand_eye.excitation_deg
    return f"not yet (turned {turned[0]:.0f} / {turned[1]:.0f} of {pipe.hand_eye.min_excitation_deg:.0f} deg)"


class TrajectoryNode(GraphNode):
    """The fused pelvis trajectory of the HSC4D graph, its map and the suit's clock offset."""

    NAME = "hsc4d_trajectory_node"
    PARAMS_FILE = HSC4D_PARAMS_FILE
    PARAMS = {
        "lidar_topic": Param("input: the hip Ouster's PointCloud2 (per-point t in ns from the stamp)"),
        "pelvis_imu_topic": Param("input: the suit's pelvis sensor_msgs/Imu"),
        "suit_odometry_topic": Param("input: the suit's own nav_msgs/Odometry"),
        "suit_rate_hz": Param("expected rate of the suit's topics", positive),
        "odometry_topic": Param("out: the fused pelvis trajectory (nav_msgs/Odometry in frame_id)"),
        "map_topic": Param("out (latched): the map of the whole site seen so far (PointCloud2 in frame_id)"),
        "offset_topic": Param("out (latched): the suit's clock offset in ns (std_msgs/Int64)"),
        "frame_id": Param("the outputs' frame (gravity aligned, origin on the ground under the first pelvis)"),
        "child_frame_id": Param("the fused pelvis's frame (the odometry's child and the /tf child)"),
        "publish_tf": Param("broadcast frame_id -> child_frame_id on /tf (needs tf2_msgs)"),
        "map_period_s": Param("period of the map output (steady time)", positive),
        "suit_wait_s": Param("a sweep waits at most this long after arriving for the suit's samples to cover it",
                             positive),
        "max_waiting_sweeps": Param("sweeps that may wait for the suit; the oldest goes on without it", positive),
        "mount_lever_m": Param("nominal LiDAR origin in the pelvis frame (x left, y up, z forward), m", numbers(3)),
        "mount_tilt_up_deg": Param("nominal tilt up of the LiDAR on the hip, deg"),
        "mount_spin_deg": Param("the LiDAR's turn about its own (spin) axis, deg: where its +x, an Ouster's "
                                "connector, points; 0 where the body faces, 180 with the connector to the back (a "
                                "tilted sensor spun 30 deg or more from it is found from the ground at the start "
                                "and used, with a WARN)"),
        "check_mount": Param("find the LiDAR's spin from the ground of the first sweeps and use it where it "
                             "differs from mount_spin_deg, with a WARN (false: the mounting exactly as set, its "
                             "hip too)"),
        "check_mount_hip": Param("with check_mount, also find the hip the LiDAR is worn on from the wearer's body "
                                 "in the first sweeps (the torso and thighs block its rays toward the body's middle) "
                                 "and use it where it is not mount_lever_m's, with a WARN"),
        "hold_s": Param("sweeps held while waiting for the jump (older ones are dropped and counted)", positive),
        "map_after_s": Param("registered capture (the wearer standing still) before the map frame is fixed",
                             non_negative),
        "max_registration_hz": Param("sweeps are registered at most this often, the others posed by the suit's "
                                     "motion (0: every sweep)", non_negative),
        "pinned_information": Param("[low, high]: a registration's shift or turn about the vertical whose "
                                    "information per point (how well the sweep's surfaces pin it) is under low "
                                    "is left to the suit's step, over high kept, linearly between ([0, 0]: every "
                                    "one kept)", numbers(2)),
        "pinned_tilt_information": Param("[low, high]: the same for a registration's tilt, left to the pelvis "
                                         "IMU's turn", numbers(2)),
        "resume_file": Param("the trajectory's state, written every resume_period_s (YAML, its local map beside it "
                             "as <file>.map.npz); read at start: a restart goes on from it without a jump, and "
                             "hsc4d_body_node takes the standing pelvis height from it ('' = off)"),
        "resume_period_s": Param("the state is written this often (steady time)", positive),
        "resume_max_gap_s": Param("a state this much older than the first sweep (or newer) is not resumed from",
                                  positive),
    }

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        p = self.params
        try:
            self._config = TrajectoryConfig(
                mount=HipMountPrior(tuple(map(float, p["mount_lever_m"])), float(p["mount_tilt_up_deg"]),
                                    float(p["mount_spin_deg"])),
                odometry=OdometryConfig(max_rate_hz=float(p["max_registration_hz"]),
                                        pinned_information=tuple(map(float, p["pinned_information"])),
                                        pinned_tilt_information=tuple(map(float, p["pinned_tilt_information"]))),
                hold_s=float(p["hold_s"]), map_after_s=float(p["map_after_s"]), suit_rate_hz=float(p["suit_rate_hz"]),
                check_mount=bool(p["check_mount"]), check_hip=bool(p["check_mount_hip"]))
        except ValueError as exc:
            raise ParameterError(str(exc)) from exc
        self.pipeline = TrajectoryPipeline(self._config)
        self._resume_file = Path(p["resume_file"]).expanduser() if p["resume_file"] else None
        self._resume: TrajectoryResume | None = None  # read at start, until the first sweep decides
        self._resume_status = "off" if self._resume_file is None else "no saved state at start"
        self._resume_writes = "none yet"  # how the writing of the state goes
        if self._resume_file is not None and self._resume_file.exists():
            try:
                self._resume = load_resume(self._resume_file)
            except ValueError as exc:  # a crash while it was written, a disk gone bad: the jump is waited for
                self._resume_status = f"not resumed: {exc}"
                self.get_logger().error(f"{self._resume_status}; waiting for the jump")
            else:
                self._resume_status = "state read, waiting for the first sweep and the suit"
        self._resumed_ns: int | None = None  # the stamp of the state last written
        self._waiting: deque[_Sweep] = deque()
        self._suit_ns = {"imu": None, "odometry": None}  # newest accepted suit stamps
        self._dropped: Counter[str] = Counter()  # of the pipeline's drops, those already counted as frames
        self._last_ns: int | None = None  # of the last sweep taken
        self._last_clock_ns: int | None = None  # ... as the LiDAR's clock read it
        self._last_received = 0.0  # monotonic s of the last cloud
        self._last_step: TrajectoryStep | None = None
        self._map_stamp_ns: int | None = None
        self._lidar_clock, self._suit_clock = SteppingClock(), SteppingClock()  # time lines across clock steps
        self._restart = SuitRestart()
        self._began_again, self._why_began = 0, ""  # new captures begun, why the last one did
        self._published = 0
        self._latency = LatencyWindow()  # cloud received -> odometry published, sweeps with no backlog before them
        self._catch_up_latency = LatencyWindow()  # ... sweeps after the sync that waited behind the backlog
        #: sweep stamp -> (monotonic s it was received, whether it came behind a backlog), sweeps after the sync
        self._received: dict[int, tuple[float, bool]] = {}
        self._odometry_pub = self.create_publisher(Odometry, p["odometry_topic"], FUSED_ODOMETRY_QOS)
        self._map_pub = self.create_publisher(PointCloud2, p["map_topic"], LATCHED)
        self._offset_pub = self.create_publisher(Int64, p["offset_topic"], LATCHED)
        self._tf_pub = tf_publisher(self) if p["publish_tf"] else None
        clouds = QoSProfile(depth=int(np.ceil(_CLOUD_QUEUE_S * p["lidar_rate_hz"])), reliability=IMU_INPUT.reliability,
                            durability=IMU_INPUT.durability)
        self.add_input(_LIDAR, p["lidar_topic"], PointCloud2, p["lidar_rate_hz"], self._on_cloud, clouds,
                       # the suit's inputs are on its own clock: not checked
                       stamped_at=1.0 / p["lidar_rate_hz"], count_missing=True)
        suit = suit_input(p["suit_rate_hz"])
        self.add_input(_SUIT_INPUTS[0], p["suit_odometry_topic"], Odometry, p["suit_rate_hz"], self._on_suit_odometry,
                       suit)
        self.add_input(_SUIT_INPUTS[1], p["pelvis_imu_topic"], Imu, p["suit_rate_hz"], self._on_pelvis, suit)
        self.create_timer(POLL_PERIOD_S, self._drain, self.group, clock=self.steady)
        self.create_timer(p["map_period_s"], self._publish_map, self.group, clock=self.steady)
        if self._resume_file is not None:
            self.create_timer(p["resume_period_s"], self._save_resume, self.group, clock=self.steady)
        self.get_logger().info("ready; " + ("going on from the saved trajectory at the first sweep" if self._resume
                                            else "waiting for the performer's jump to sync the suit's clock"))

    def _on_cloud(self, msg: PointCloud2) -> int:
        received = self._last_received = time.monotonic()
        stamp_ns, _ = read_header(msg)
        try:
            points, t = cloud_to_xyz_time(msg)
        except MalformedMessageError:
            self.count_frame("skipped: malformed cloud")
            raise
        if points.shape[0] == 0:
            self.count_frame("skipped: empty cloud", f"{stamp_ns}: no finite point")
            return stamp_ns
        # a LiDAR sends no stale sweep: the first one behind is the step (and the outputs' spacing stays whole for
        # the body node, which finds the step again from their stamps)
        try:
            line_ns = self.on_time_line(self._lidar_clock, _LIDAR, stamp_ns, confirm=False)
        except MalformedMessageError as exc:  # of the capture before a new one began
            self.count_frame(_BEGAN_AGAIN, f"{stamp_ns}: {exc}")
            raise
        point_ns = line_ns + t.astype(np.int64)
        self._waiting.append(_Sweep(line_ns, points.astype(np.float64), point_ns, received, int(point_ns.max()),
                                    stamp_ns))
        self._take_suit()
        if not self._decide_resume():
            return stamp_ns
        while len(self._waiting) > self.params["max_waiting_sweeps"]:
            self._take(self._waiting.popleft())  # goes on with the suit data there is
        self._drain()
        return stamp_ns

    def _on_pelvis(self, msg: Imu) -> int:
        sample = msg_to_imu(msg)
        line_ns = self.on_time_line(self._suit_clock, _SUIT_INPUTS[1], sample.stamp_ns)
        reason = self.pipeline.add_pelvis_imu(replace(sample, stamp_ns=line_ns))
        if reason is not None:
            raise MalformedMessageError(reason)
        self._suit_ns["imu"] = max(line_ns, self._suit_ns["imu"] or line_ns)  # samples may come out of order
        self._take_covered()
        return sample.stamp_ns

    def _on_suit_odometry(self, msg: Odometry) -> int:
        odometry = msg_to_odometry(msg)
        line_ns = self.on_time_line(self._suit_clock, _SUIT_INPUTS[0], odometry.stamp_ns)
        began = self._restart.add(odometry.stamp_ns, odometry.position, odometry.quat)
        if began is not None:
            self._begin_again(began)
            line_ns = self.on_time_line(self._suit_clock, _SUIT_INPUTS[0], odometry.stamp_ns)
        reason = self.pipeline.add_suit_odometry(line_ns, odometry.position, odometry.quat)
        if reason is not None:
            raise MalformedMessageError(reason)
        self._suit_ns["odometry"] = max(line_ns, self._suit_ns["odometry"] or line_ns)
        self._take_covered()
        return odometry.stamp_ns

    def _decide_resume(self) -> bool:
        """While a saved state waits (the sweeps wait with it): once the suit has sent its odometry (or has not for
        ``suit_wait_s`` after the first sweep), go on from the state or not; whether the sweeps may be taken."""
        state = self._resume
        if state is None:
            return True
        first, suit_ns = self._waiting[0] if self._waiting else None, self._suit_ns["odometry"]
        if first is None or (suit_ns is None and time.monotonic() - first.received < self.params["suit_wait_s"]):
            return False
        self._resume = None
        refusal = resume_refusal(state, first.stamp_ns, self.params["resume_max_gap_s"])
        if refusal is None and suit_ns is None:
            refusal = f"no suit odometry within {self.params['suit_wait_s']} s of the first sweep"
        elif refusal is None and abs(suit_ns - (first.stamp_ns + state.offset_ns)) > _RESUME_SUIT_SLACK_S * 1e9:
            refusal = (f"the suit's clock is {(suit_ns - first.stamp_ns - state.offset_ns) * 1e-9:+.1f} s from where "
                       "the saved offset puts it (another capture, or the suit restarted)")
        self._resume_from(state, first.stamp_ns, refusal)
        return True

    def _resume_from(self, state: TrajectoryResume, stamp_ns: int, refusal: str | None) -> None:
        """Go on from the saved ``state`` at the first sweep (stamped ``stamp_ns``) unless ``refusal`` says why not
        (then wait for the jump); say which."""
        if refusal is not None:
            self._resume_status = f"not resumed: {refusal}; waiting for the jump"
            self.get_logger().warning(f"{self._resume_file}: {self._resume_status}")
            return
        self.pipeline.resume(state)
        self._offset_pub.publish(Int64(data=int(state.offset_ns)))
        gap_s = (stamp_ns - state.stamp_ns) * 1e-9
        self._resume_status = f"resumed from the state {gap_s:.1f} s before the first sweep"
        self.get_logger().info(f"{self._resume_file}: {self._resume_status} (suit clock {state.offset_ns * 1e-6:+.1f} "
                               f"ms from the LiDAR's, {len(state.map_points)} map points)")

    def _save_resume(self) -> None:
        """Write the trajectory's state (on the sensors' clocks as they read) if it moved on since the last."""
        try:
            state = self.pipeline.resume_state()
            if state is None or state.stamp_ns == self._resumed_ns:
                return
            stamp_ns = self._lidar_clock.external(state.stamp_ns)
            offset_ns = self._suit_clock.external(state.stamp_ns + state.offset_ns) - stamp_ns
            save_resume(replace(state, stamp_ns=stamp_ns, offset_ns=offset_ns), self._resume_file)
        except (OSError, ValueError) as exc:
            self._resume_writes = f"failed: {exc}"
            self.get_logger().error(f"cannot write the trajectory's state: {exc}", throttle_duration_sec=10.0)
            return
        self._resumed_ns = state.stamp_ns
        self._resume_writes = f"last at {stamp_ns * 1e-9:.1f} s"

    def _forget_resume(self) -> None:
        """A new capture began: the saved state is the last one's (a restart must wait for the new jump)."""
        if self._resume_file is None:
            return
        self._resumed_ns = None
        try:
            for path in (self._resume_file, map_file(self._resume_file)):
                path.unlink(missing_ok=True)
        except OSError as exc:  # a restart then refuses the state by its stamps, or by the suit's clock
            self._resume_status = f"a new capture began: the saved state could not be removed: {exc}"
            self.get_logger().error(self._resume_status)
            return
        self._resume_status = "a new capture began: the saved state removed"

    def _take_suit(self) -> None:
        """Take every suit sample already received (the sweeps' callbacks would otherwise let the suit's queues
        fill while they come round on every executor wait: at 20 Hz the node took 1704 of 3000 pelvis samples)."""
        for name in _SUIT_INPUTS:
            self.take_waiting(name)

    def _suit_covers(self, sweep: _Sweep) -> bool:
        """Whether the suit's samples cover the sweep (:meth:`TrajectoryPipeline.suit_covers`; always, before the
        offset is known: held). Both suit streams must have reached its last point first (a cheap test)."""
        offset = self.pipeline.offset_ns
        if offset is None:
            return True
        end = sweep.end_ns + offset
        return (all(s is not None and s >= end for s in self._suit_ns.values())
                and self.pipeline.suit_covers(sweep.stamp_ns, sweep.end_ns))

    def _take_covered(self) -> None:
        """Once synced, take the waiting sweeps the suit now covers as its samples come in (not at the next
        drain: a sweep waited up to the drain's period, 20 ms, after its suit data was in)."""
        while (self._decide_resume() and self.pipeline.offset_ns is not None and self._waiting
               and self._suit_covers(self._waiting[0])):
            self._take(self._waiting.popleft())

    def _drain(self) -> None:
        """Take the waiting sweeps the suit covers, or that waited long enough; else register one sweep of the
        pipeline's backlog (the sweeps held until the jump), one per call so that the suit's samples keep coming
        in between."""
        self._take_suit()
        if not self._decide_resume():
            return
        now = time.monotonic()
        taken = False
        while self._waiting and (self._suit_covers(self._waiting[0])
                                 or now - self._waiting[0].received >= self.params["suit_wait_s"]):
            self._take(self._waiting.popleft())
            taken = True
        if not taken and now - self._last_received >= self.params["suit_wait_s"]:  # no sweeps coming in
            self._publish_steps(self.pipeline.catch_up(1))

    def _begin_again(self, reason: str) -> None:
        """A new capture began (``reason``): the last one's sweeps go on with the suit data there is and what its
        trajectory still holds is skipped; a new trajectory waits for the new capture's jump, with the sweeps of
        the new capture received so far (after the LiDAR's step back, if it came first)."""
        self.get_logger().warning(f"a new capture began: {reason}; the trajectory starts again and waits for "
                                  "its jump")
        last, new, newest = [], [], self._last_clock_ns
        for sweep in self._waiting:
            if new or stepped_back(sweep.clock_ns, newest):
                new.append(sweep)
            else:
                last.append(sweep)
            newest = sweep.clock_ns
        self._waiting.clear()
        self._resume = None  # a state waiting for the first sweep was the last capture's
        self._forget_resume()
        for sweep in last:
            self._take(sweep)
        self._publish_steps(self.pipeline.catch_up())
        for _ in range(self.pipeline.waiting):
            self.count_frame(_BEGAN_AGAIN, reason)
        self.pipeline = TrajectoryPipeline(self._config)
        self._dropped.clear()
        self._received.clear()
        self._suit_ns = dict.fromkeys(self._suit_ns)
        self._last_ns = self._last_clock_ns = self._last_step = self._map_stamp_ns = None
        # the suit's clock stepped back with the new capture; the LiDAR's may not have, or long ago: a sweep it
        # sends within a LiDAR queue's length of its last one is the last capture's
        self._suit_clock.begin_again(ahead_ns=int(SUIT_QUEUE_S * 1e9))
        self._lidar_clock.begin_again(ahead_ns=int(_CLOUD_QUEUE_S * 1e9), crossed_within_ns=int(_CLOUD_QUEUE_S * 1e9))
        self._began_again, self._why_began = self._began_again + 1, reason
        for sweep in new:
            shift = self._lidar_clock.internal(_LIDAR, sweep.clock_ns, confirm=False) - sweep.stamp_ns
            self._waiting.append(replace(sweep, stamp_ns=sweep.stamp_ns + shift, point_ns=sweep.point_ns + shift,
                                         end_ns=sweep.end_ns + shift))

    def _take(self, sweep: _Sweep) -> None:
        """Give one sweep to the pipeline and publish what comes out."""
        if self._last_ns is not None and sweep.stamp_ns <= self._last_ns:
            self.count_frame("skipped: not after the last sweep", f"{sweep.stamp_ns} <= {self._last_ns}")
            return
        self._last_ns, self._last_clock_ns = sweep.stamp_ns, sweep.clock_ns
        synced = self.pipeline.offset_ns is not None
        if synced:  # its latency is measured (those held for the jump wait for it by design)
            self._received[sweep.stamp_ns] = (sweep.received, self.pipeline.backlog > 0)
            while len(self._received) > _MAX_TRACKED:  # dropped from the backlog, never output
                del self._received[next(iter(self._received))]
        start = time.monotonic()
        spin_checked = self.pipeline.spin.decided
        steps = self.pipeline.add_sweep(sweep.points, sweep.point_ns, sweep.stamp_ns, max_register=2)
        if not spin_checked:
            for check, used in ((self.pipeline.spin, self.pipeline.spin.correction_deg),
                                (self.pipeline.side, self.pipeline.side.mirrored)):
                if used:
                    self.get_logger().warning(f"mounting: {check.status}")
        budget = _CATCH_UP_SHARE / self.input_rate_hz(_LIDAR)  # of the period the sweeps' stamps show
        while self.pipeline.backlog and self.pipeline.offset_ns is not None and time.monotonic() - start < budget:
            steps += self.pipeline.catch_up(1)
        if not synced and self.pipeline.offset_ns is not None:
            offset = int(self.pipeline.offset_ns)
            self._offset_pub.publish(Int64(data=offset))
            self.get_logger().info(f"jump seen: the suit's clock is {offset * 1e-6:+.1f} ms from the LiDAR's")
        self._publish_steps(steps)

    def _publish_steps(self, steps: list[TrajectoryStep]) -> None:
        """Count the sweeps the pipeline dropped, then publish the steps it output."""
        self._count_drops()
        for step in steps:
            self._publish(step, self._received.pop(step.sweep_ns, None))

    def _count_drops(self) -> None:
        """Count the sweeps the pipeline dropped since the last call as skipped frames."""
        for key, what in _DROPPED.items():
            for _ in range(self.pipeline.counts[key] - self._dropped[key]):
                self.count_frame(what)
            self._dropped[key] = self.pipeline.counts[key]

    def _publish(self, step: TrajectoryStep, received: tuple[float, bool] | None) -> None:
        """The fused pose of one sweep: odometry, /tf; its latency from ``received`` (its cloud's receipt and
        whether it waited behind the backlog; None for a sweep held for the jump)."""
        p = self.params
        stamp_ns = self._lidar_clock.external(step.stamp_ns)  # as the LiDAR's clock read at that moment
        R, position = step.pelvis[:3, :3], step.pelvis[:3, 3]
        quat = matrix_to_quat(R)
        linear = angular = None
        last = self._last_step
        if last is not None and 0 < step.stamp_ns - last.stamp_ns <= _MAX_TWIST_DT_S * 1e9:
            dt = (step.stamp_ns - last.stamp_ns) * 1e-9
            linear = R.T @ (position - last.pelvis[:3, 3]) / dt
            angular = matrix_to_axis_angle(last.pelvis[:3, :3].T @ R) / dt
        self._last_step = step
        self._odometry_pub.publish(odometry_to_msg(self.backend, stamp_ns, p["frame_id"], p["child_frame_id"],
                                                   position, quat, linear, angular))
        if self._tf_pub is not None:
            self._tf_pub.publish(tf_message(self.backend, [transform_stamped_to_msg(
                self.backend, stamp_ns, p["frame_id"], p["child_frame_id"], position, quat)]))
        self._published += 1
        if received is not None:
            (self._catch_up_latency if received[1] else self._latency).add(time.monotonic() - received[0])
        self.pipeline.add_to_map(step)  # after the pose is out: off its latency

    def _publish_map(self) -> None:
        last = self._last_step
        if last is None or last.stamp_ns == self._map_stamp_ns:
            return
        points = self.pipeline.map_points()
        if points is None:
            return
        self._map_pub.publish(xyz_to_cloud(self.backend, points, self._lidar_clock.external(last.stamp_ns),
                                           self.params["frame_id"]))
        self._map_stamp_ns = last.stamp_ns

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """The trajectory's state, the suit's clock offset, the mounting's estimate, what was not believed."""
        pipe = self.pipeline
        level = DiagnosticLevel.OK if pipe.status == "tracking" else DiagnosticLevel.WARN
        offset = pipe.offset_ns
        values: dict[str, Any] = {
            OFFSET_VALUE: "unknown" if offset is None else f"{offset * 1e-6:.1f}",
            "mounting levelled by (deg)": f"{pipe.mount_levelled_deg:.2f}",
            "suit odometry's pelvis up vs its pelvis IMU's (deg)": f"{pipe.odometry_tilt_deg:.2f}",
            "mounting turned about the body by (deg)": f"{pipe.mount_yaw_deg:.2f}",
            MOUNT_SPIN_VALUE: pipe.spin.status,
            MOUNT_HIP_VALUE: pipe.side.status,
            "body axis, walk's turns vs levelled (deg)": _mount_check(pipe),
            "lever arm in the pelvis frame (m)": " ".join(f"{v:+.3f}" for v in pipe.lever_m),
            "lever arm sigma (m)": " ".join(f"{v:.3f}" for v in pipe.lever.sigma_m),
            "stride scale of the suit": f"{pipe.stride_scale.value:.3f}",
            "pelvis gyro bias (deg/s)": " ".join(f"{v:+.3f}" for v in np.degrees(pipe.rotation.gyro_bias.value)),
            "pelvis gyro bias, still time averaged (s)": f"{pipe.rotation.gyro_bias.still_s:.1f}",
            "odometry published": self._published,
            "map points": self.pipeline.site.size,
            "map points not kept (full)": self.pipeline.site.refused,
            "clock steps back (LiDAR, suit)": f"{len(self._lidar_clock.steps_ns)}, {len(self._suit_clock.steps_ns)}",
            "new captures begun": self._began_again,
            "resume": self._resume_status,
            "resume state written": self._resume_writes,
            **({"last new capture": self._why_began} if self._began_again else {}),
            "pending": pipe.waiting + len(self._waiting),
            **{k: v for k, v in sorted(pipe.counts.items()) if k not in _DROPPED},
            **self._latency.values("latency_ms"),
            **self._catch_up_latency.values("catch_up_latency_ms"),
        }
        began = "a new capture began (a bag played again?); " if self._began_again and offset is None else ""
        return level, began + pipe.status, values


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros hsc4d_trajectory_node``."""
    return run_nodes(TrajectoryNode.NAME, __doc__.split("\n\n")[0], [TrajectoryNode], [TrajectoryNode], argv)


if __name__ == "__main__":
    raise SystemExit(main())
