"""hsc4d_body_node: the suit's 17 segments on the fused pelvis trajectory, as the contract's pose outputs in ``map``.

For each fused pelvis pose of ``hsc4d_trajectory_node`` (``/hsc4d/odometry``)
it waits until every suit segment has a sample at that moment on the suit's
clock (the pose's stamp plus the offset ``hsc4d_trajectory_node`` found from
the jump, ``/hsc4d/suit_clock_offset``): ``suit_wait_s`` at most, or for as
long as the segments it waits for are still sending, up to the suit queues'
depth (a node that was busy works off the samples queued meanwhile before its
poses give up on them). Then it poses the body
(:class:`lip_ros.hsc4d.suit_body.SuitBody`) and publishes
``/hsc4d/joint_states``, ``/hsc4d/root_pose`` and ``/hsc4d/joint_poses`` with
the pose's stamp. The skeleton is the contract's scaled by ``body_scale``;
with ``body_scale`` 0 it is scaled to the pelvis height of the first fused pose
(the wearer stands still in A-pose there, and ``map``'s origin is on the ground
under that pelvis), and the scale is logged and reported. The suit's topics
(17 x 100 Hz) are polled, taken every 20 ms and as a pose comes in, rather
than each waking the executor: that halved the node's CPU
(``GraphNode.add_input(polled=True)``).

With ``foot_lock`` (the default) the standing feet of the fused body, and of
the optimised one below, are held where they stood
(:class:`lip_ros.hsc4d.foot_lock.FootLock`, one for each): which foot stands
comes from the suit's own feet (its segments on its own ``/mocap/odometry``,
where a standing foot is still), and the leg's hip and knee are turned to keep
its foot joint there; the pelvis stays the body's. A frame without
the suit's odometry near it keeps the feet that stood standing, for up to
half a second; a new capture starts the stances again. The suit's pelvis is
interpolated between its samples at each frame's moment. The odometry's
orientation is checked against the pelvis segment's once per capture, as the
trajectory node checks it: an odometry in other axes (a ROS base_link's, say)
is read in the segment's (``suit_track.odometry_axes``), else the suit's own
feet would turn about its pelvis and never stand.

With ``optimise_window`` > 0 it also runs the scene-aware optimisation
(:class:`lip_ros.hsc4d.scene_optimisation.SceneOptimiser`): each posed frame
joins a window, with the feet as the suit alone places them (its segments on
its own ``/mocap/odometry``: which foot stands); once the window is full it is
optimised on the latest ``/hsc4d/map`` and published, frame by frame with their
own stamps, on ``/hsc4d/optimised/odometry`` and ``/hsc4d/optimised/{joint_states,
root_pose,joint_poses}`` (one window, 10 s at 10 Hz, behind the fused output).
Each window is solved on a thread of its own
(:class:`lip_ros.hsc4d.background_optimiser.BackgroundOptimiser`): the node
goes on taking the suit's samples and posing meanwhile.
The first window also measures how high the foot joint stands
above its sole, which needs the ground under the standing feet in the map
(points near a standing foot, ``SceneOptimisationConfig.support_radius_m``,
not only at the search disc's edge); the ground the wearer stood on at the start is mapped only once they walked
away (their own body hides it), so that window may wait for a later map, a
window or ``max_wait_s`` (20 s) long, whichever is longer. A partial window is
optimised once no fused pose has come for ``optimise_flush_s`` (the end of a
capture). With ``body_scale`` 0 the optimised body takes the legs' length from
the walk (:mod:`lip_ros.hsc4d.leg_scale`: the fused pelvis's steps over a
standing foot against the suit's legs; the pelvis height's size rests on the
hip LiDAR's nominal lever arm along the body), from the window in which it is
first believed on, and is published at that size (``body scale (legs from the
walk)`` on ``/diagnostics``); the fused body's outputs take it too, as the
optimiser had it at its last window, about the fused pelvis (``body scale``;
how far the standing pelvis stood off those legs, the lever arm's part along
the body off its nominal one, ``standing pelvis height off the walk's
legs``): their pelvis stays ``/hsc4d/odometry``'s, so their feet stand that
far off the map's ground, as the optimised body's foot joints do (its sole
height takes it). A given ``body_scale`` is kept for both. Frames that cannot be
optimised (no suit odometry near them; no map, or no ground under the first
window's feet by then or at the end) are counted by reason on
``/diagnostics``.

The LiDAR's and the suit's clocks may step back (a PTP step): the node keeps
each on its own time line as the trajectory node does
(:class:`lip_ros.core.clock.SteppingClock`), matches the suit's samples to the
poses there, and stamps its outputs with the stamps of the fused poses. When the
suit's pelvis jumps across its clock's step back (a bag played again: the rule
the trajectory node starts again by, :class:`lip_ros.hsc4d.suit_restart.SuitRestart`,
on the same ``/mocap/odometry``), a new capture began: the suit's samples go on
on its time line, the last capture's poses still coming are posed as before,
and the new capture's first fused pose (behind the last one, or the first after
the new capture's offset) is put on the suit's time line
(:meth:`lip_ros.core.clock.SteppingClock.realign`: the new offset holds
between the two clocks' stamps); there the optimiser (its sole height, the map)
and the body's scale start again, while the last capture's optimiser solves
its last windows with what there is on its last map, as the drain comes round.
The maps that come between are not used (which capture's is not known).
"""

from __future__ import annotations

import time
from collections import Counter, deque
from dataclasses import dataclass, replace
from pathlib import Path
from traceback import format_exception
from typing import Any, NamedTuple

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, PointCloud2
from std_msgs.msg import Int64

from lip_msgs_py import (
    DiagnosticLevel,
    MalformedMessageError,
    cloud_to_xyz,
    msg_to_imu,
    msg_to_odometry,
    odometry_to_msg,
    rclpy_message_class,
)
from lip_msgs_py.cdr import cdr_stamp, imu_samples
from lip_ros.core.clock import SteppingClock, stepped_back
from lip_ros.core.rotations import matrix_to_quat, quat_to_matrix
from lip_ros.core.skeleton import load_skeleton
from lip_ros.core.torch_runtime import set_threads
from lip_ros.hsc4d.background_optimiser import BackgroundOptimiser
from lip_ros.hsc4d.foot_lock import FootLock
from lip_ros.hsc4d.resume import TrajectoryResume, load_resume, resume_refusal
from lip_ros.hsc4d.scene_optimisation import NoGroundYet, SceneOptimisationConfig, SceneOptimiser, WindowResult
from lip_ros.hsc4d.sensors import HSC4D_TOPICS, OPTIMISED_ODOMETRY_TOPIC, OPTIMISED_TOPICS, PELVIS_FRAME
from lip_ros.hsc4d.suit_body import (
    FEET,
    BodyPose,
    SuitBody,
    SuitBodyConfig,
    bent_legs,
    leg_chains,
    moved_body,
    resized_body,
)
from lip_ros.hsc4d.suit_restart import SuitRestart
from lip_ros.hsc4d.suit_track import Sample, axes_columns, odometry_axes, pose_between
from lip_ros.hsc4d.trajectory import TrajectoryConfig
from lip_ros.nodes.base import (
    LATCHED,
    POLL_PERIOD_S,
    RELIABLE,
    SUIT_QUEUE_S,
    GraphNode,
    LatencyWindow,
    Param,
    ParameterError,
    non_negative,
    positive,
    run_nodes,
    suit_input,
)
from lip_ros.nodes.hsc4d import FUSED_ODOMETRY_QOS, HSC4D_PARAMS_FILE, OPTIMISING_VALUE
from lip_ros.nodes.hsc4d.trajectory import TrajectoryNode
from lip_ros.outputs import pose_cdr

__all__ = ["BodyNode", "main"]

_MAX_ODOMETRY_TILT_DEG = TrajectoryConfig.max_odometry_tilt_deg  # as the trajectory node checks it
_SOLVE_STOP_WAIT_S = 5.0  # at shutdown, how long to wait for an optimisation window being solved
_POSE_TYPES = (("joint_states", "sensor_msgs/msg/JointState"), ("root_pose", "geometry_msgs/msg/PoseStamped"),
               ("joint_poses", "geometry_msgs/msg/PoseArray"))


def _segment_topics(value: Any) -> str | None:
    """Check: one topic per suit segment, in the skeleton's ``suit_imus`` order."""
    n = len(load_skeleton().suit_imus)
    ok = isinstance(value, (list, tuple)) and len(value) == n and all(isinstance(v, str) and v for v in value)
    return None if ok else f"must list {n} topics (the skeleton's suit_imus, in order), got {value!r}"


@dataclass
class _FusedPose:
    """A fused pelvis pose waiting for the suit's samples."""

    stamp_ns: int  # as received and published: the LiDAR's clock
    line_ns: int  # on the node's LiDAR time line (:class:`SteppingClock`), where the suit's samples are matched
    frame_id: str
    T_map_P: np.ndarray
    received: float  # monotonic s
    deadline: float  # it goes on with the suit data there is then (monotonic s)


class _OptimisedFrame(NamedTuple):
    """A posed frame in the optimiser: what its optimised body is published with, and its foot lock's inputs."""

    stamp_ns: int
    frame_id: str
    pose: BodyPose  # on the fused pelvis
    T_map_P: np.ndarray  # the fused pelvis
    t_s: float  # on the node's LiDAR time line
    suit_feet: np.ndarray  # (2, 3): the suit's own foot joints


class BodyNode(GraphNode):
    """The fused body of the HSC4D graph."""

    NAME = "hsc4d_body_node"
    PARAMS_FILE = HSC4D_PARAMS_FILE
    PARAMS = {
        "suit_imu_topics": Param("input: the suit's 17 segment sensor_msgs/Imu topics, in the skeleton's suit_imus "
                                 "order", _segment_topics),
        "suit_rate_hz": TrajectoryNode.PARAMS["suit_rate_hz"],
        "odometry_topic": Param("input: the fused pelvis trajectory of hsc4d_trajectory_node"),
        "offset_topic": Param("input (latched): the suit's clock offset of hsc4d_trajectory_node"),
        "body_scale": Param("the performer's size relative to the contract skeleton (0 = from the standing pelvis "
                            "height of the first fused pose, then, with optimise_window > 0, from the legs' length "
                            "the walk gives)", non_negative),
        "suit_wait_s": Param("a pose waits this long after arriving for every segment's sample; longer (up to the "
                             "suit queues' 5 s) while the segments it waits for still send", positive),
        "max_waiting_poses": Param("poses that may wait for the suit; the oldest goes on with what there is",
                                   positive),
        "max_imu_gap_s": Param("widest gap between two suit samples interpolated across", positive),
        "suit_odometry_topic": Param("input: the suit's own nav_msgs/Odometry (a new capture beginning; which "
                                     "foot stands, for the foot lock and the optimisation)"),
        "map_topic": Param("input (latched): the map of hsc4d_trajectory_node (the ground under the feet)"),
        "foot_lock": Param("hold the standing feet of the fused and the optimised bodies where they stood (which "
                           "foot stands: the suit's own feet on suit_odometry_topic; lip_ros.hsc4d.foot_lock)"),
        "optimise_window": Param("frames per scene-aware optimisation window (0: no optimisation)",
                                 lambda v: None if v == 0 or v >= 3 else f"must be 0 or >= 3, got {v}"),
        "optimise_flush_s": Param("a partial window is optimised once no fused pose came for this long", positive),
        "optimise_threads": Param("torch's CPU threads for the optimisation (1: the other core stays the trajectory "
                                  "node's)", positive),
        "resume_file": Param("hsc4d_trajectory_node's state (read at start): with body_scale 0, a graph started "
                             "again mid-capture scales the body to the standing pelvis height in it ('' = off)"),
        "resume_max_gap_s": TrajectoryNode.PARAMS["resume_max_gap_s"],
    }

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        p = self.params
        gap_ns = int(p["max_imu_gap_s"] * 1e9)
        try:
            capacity = TrajectoryConfig(suit_rate_hz=p["suit_rate_hz"]).suit_capacity
            self.body = SuitBody(load_skeleton(), SuitBodyConfig(capacity=capacity, body_scale=p["body_scale"] or 1.0,
                                                                 max_gap_ns=gap_ns, max_hold_ns=gap_ns))
        except ValueError as exc:
            raise ParameterError(str(exc)) from exc
        self._scale_from_height = p["body_scale"] == 0
        self._standing_m: float | None = None  # the standing pelvis height the body was scaled to (None: given)
        self._fused_ratio = 1.0  # the fused body's size over the standing height's (the legs' from the walk)
        self._resumed: TrajectoryResume | None = None  # the trajectory's state at start, until the first pose
        resume = Path(p["resume_file"]).expanduser() if p["resume_file"] else None
        if resume is not None and resume.exists() and self._scale_from_height:
            try:
                self._resumed = load_resume(resume, with_map=False)
            except ValueError as exc:  # the trajectory node says so too, and waits for the jump
                self.get_logger().warning(f"the body is scaled to its first fused pose: {exc}")
        self._offset_ns: int | None = None
        self._waiting: deque[_FusedPose] = deque()
        self._lidar_clock, self._suit_clock = SteppingClock(), SteppingClock()  # time lines across clock steps
        self._restart = SuitRestart()
        self._began_again = 0  # new captures begun
        #: while a new capture began and its first fused pose has not come: the last fused stamp before it, and
        #: whether an offset came since
        self._new_capture: tuple[int | None, bool] | None = None
        self._last_fused_ns: int | None = None
        self._degraded = 0
        self._latency = LatencyWindow()  # fused pose received -> body published
        self._out = self._pose_publishers(HSC4D_TOPICS)
        self._optimiser = None
        self._lock = FootLock(self.body.skeleton) if p["foot_lock"] else None
        # the optimised body's foot lock of each optimiser (the one now and those of the last captures closing), by
        # id; the anchors let go by those of captures closed
        self._optimised_locks: dict[int, FootLock] = {}
        self._optimised_released = 0
        self._feet = [self.body.skeleton.index(f) for f in FEET]
        # the suit's own pelvis poses (which foot stands), for the foot lock and the optimisation
        self._suit_stamps: deque[int] = deque(maxlen=self.body.config.capacity)
        self._suit_poses: deque[Sample] = deque(maxlen=self.body.config.capacity)
        # the suit odometry's pelvis up vs its pelvis IMU's (NaN: not checked yet), and the segment's axes in the
        # odometry's where another convention is found (once per capture)
        self._odometry_tilt_deg = float("nan")
        self._odometry_axes: np.ndarray | None = None
        if p["optimise_window"]:
            set_threads(p["optimise_threads"])
            # the optimised body's legs take their length from the walk unless the body's size is given; its
            # windows solved on a thread of their own; each frame's record: (stamp, frame_id, body, T_map_P)
            self._optimiser = BackgroundOptimiser(SceneOptimiser(replace(
                SceneOptimisationConfig(), window=p["optimise_window"], legs_from_walk=self._scale_from_height)))
            self._closing: list[BackgroundOptimiser] = []  # the last captures': their last windows being solved
            self._lock_optimised(self._optimiser)
            self._last_pose_at = time.monotonic()
            self._optimised = 0
            self._not_optimised: Counter[str] = Counter()
            self._window_latency = LatencyWindow()  # time per window optimised
            self._opt_odometry = self.create_publisher(Odometry, OPTIMISED_ODOMETRY_TOPIC, RELIABLE)
            self._opt_out = self._pose_publishers(OPTIMISED_TOPICS)
            self.create_subscription(PointCloud2, p["map_topic"], self._on_map, LATCHED, callback_group=self.group)
        # taken before the segments' samples (polled in this order): a new capture is seen before they are put on
        # the time line of the last one
        self.add_input("suit odometry", p["suit_odometry_topic"], Odometry, p["suit_rate_hz"],
                       self._on_suit_odometry, suit_input(p["suit_rate_hz"]), polled=True)
        self.create_subscription(Int64, p["offset_topic"], self._on_offset, LATCHED, callback_group=self.group)
        self.add_input("fused odometry", p["odometry_topic"], Odometry, p["lidar_rate_hz"], self._on_odometry,
                       FUSED_ODOMETRY_QOS, watched=False)  # the trajectory node's: none until the jump is seen
        # not decoded yet: each sample's bytes and what its stamp is moved on by on the suit's time line
        self._raw: dict[str, list[tuple[bytes, int]]] = {s: [] for s in self.body.segments}
        self._newest: dict[str, int] = {}  # each segment's newest stamp received
        self._arrived: dict[str, float] = {}  # ... and when its last sample came (monotonic s)
        self._rejected: Counter[str] = Counter()  # suit samples, by reason
        for segment, topic in zip(self.body.segments, p["suit_imu_topics"]):
            self.add_input(f"suit {segment}", topic, Imu, p["suit_rate_hz"],
                           lambda data, segment=segment: self._on_imu(segment, data), suit_input(p["suit_rate_hz"]),
                           raw=True, polled=True)
        self.create_timer(POLL_PERIOD_S, self._drain, self.group, clock=self.steady)
        self.get_logger().info("ready; waiting for the trajectory node's fused poses")

    def destroy_node(self) -> None:
        """Wait a while for an optimisation window being solved (a thread left in torch as the interpreter shuts
        down may abort the process), then destroy the node."""
        if self._optimiser is not None:
            deadline = time.monotonic() + _SOLVE_STOP_WAIT_S
            for live in (self._optimiser, *self._closing):
                live.close(deadline)
        super().destroy_node()

    def _pose_publishers(self, topics: Any) -> dict[str, Any]:
        """A reliable publisher per pose output of ``topics`` (a PoseTopics)."""
        return {getattr(topics, name): self.create_publisher(rclpy_message_class(msgtype), getattr(topics, name),
                                                             RELIABLE) for name, msgtype in _POSE_TYPES}

    def _on_map(self, msg: PointCloud2) -> None:
        if self._new_capture is not None:  # the last capture's or the new one's: not known which
            self._not_optimised["optimisation: maps not used, a new capture began"] += 1
            return
        try:
            self._optimiser.map = cloud_to_xyz(msg).astype(np.float64)
        except MalformedMessageError as exc:
            self.get_logger().warning(f"map not used: {exc}", throttle_duration_sec=5.0)
            self._not_optimised["optimisation: maps not used, malformed"] += 1
            return
        self._solve(self._optimiser)  # a window may be waiting for it

    def _on_suit_odometry(self, msg: Odometry) -> int:
        odometry = msg_to_odometry(msg)
        norm = float(np.linalg.norm(odometry.quat))
        if not (np.isfinite(odometry.position).all() and np.isfinite(norm) and norm > 0.5):
            raise MalformedMessageError("non-finite position or degenerate quaternion")
        line_ns = self.on_time_line(self._suit_clock, "suit odometry", odometry.stamp_ns)
        began = self._restart.add(odometry.stamp_ns, odometry.position, odometry.quat)
        if began is not None:
            self.get_logger().warning(f"a new capture began: {began}; its poses go on from its first fused pose")
            self._new_capture = (self._last_fused_ns, False)
            self._began_again += 1
        if self._optimiser is None and self._lock is None:
            return odometry.stamp_ns
        if self._suit_stamps and line_ns <= self._suit_stamps[-1]:
            raise MalformedMessageError("not after the last sample")
        self._suit_stamps.append(line_ns)
        self._suit_poses.append((line_ns, np.asarray(odometry.position, dtype=np.float64), odometry.quat / norm))
        return odometry.stamp_ns

    def _first_of_new_capture(self, stamp_ns: int) -> int:
        """The new capture's first fused pose (stamped ``stamp_ns``): pose the last capture's poses waiting (its
        optimiser solves its last windows with what there is on its last map, as the drain comes round), start the
        optimiser and the body's scale again; its time on the suit's time line."""
        while self._waiting:
            self._pose(self._waiting.popleft())
        if self._optimiser is not None:
            self._closing.append(self._optimiser)  # its feet held on by its own lock
            self._optimiser = BackgroundOptimiser(SceneOptimiser(self._optimiser.config))
            self._lock_optimised(self._optimiser)
        self._scale_from_height = self.params["body_scale"] == 0
        if self._lock is not None:
            self._lock.reset()
        self._odometry_tilt_deg, self._odometry_axes = float("nan"), None
        self._new_capture = None
        return self._lidar_clock.realign("fused odometry", stamp_ns, self._suit_clock.shift_ns)

    def _lock_optimised(self, live: BackgroundOptimiser) -> None:
        """Give ``live``'s optimised body a foot lock of its own (with ``foot_lock``)."""
        if self.params["foot_lock"]:
            self._optimised_locks[id(live)] = FootLock(self.body.skeleton)

    def _suit_pose(self, suit_ns: int) -> np.ndarray | None:
        """The suit's own pelvis pose (4, 4) at ``suit_ns``: between the samples around it (as the trajectory's
        :class:`~lip_ros.hsc4d.suit_track.SuitTrack`, which the evaluation's body uses) when they are at most
        max_imu_gap_s apart, else the nearest sample within max_imu_gap_s (the next one not here yet), or None."""
        if not self._suit_stamps:
            return None
        gap_ns = self.params["max_imu_gap_s"] * 1e9
        stamps = np.fromiter(self._suit_stamps, dtype=np.int64, count=len(self._suit_stamps))
        k = int(np.searchsorted(stamps, suit_ns))
        if 0 < k < len(stamps) and stamps[k] - stamps[k - 1] <= gap_ns:
            return pose_between(suit_ns, self._suit_poses[k - 1], self._suit_poses[k])
        k = min(range(max(k - 1, 0), min(k + 1, len(stamps))), key=lambda i: abs(stamps[i] - suit_ns))
        if abs(stamps[k] - suit_ns) > gap_ns:
            return None
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = quat_to_matrix(self._suit_poses[k][2]), self._suit_poses[k][1]
        return T

    def _suit_own(self, fused: _FusedPose) -> tuple[np.ndarray, BodyPose] | None:
        """The suit's own pelvis pose at a fused pose's moment and its body on it (where a standing foot is still),
        or None (no suit odometry near it)."""
        suit_ns = fused.line_ns + self._offset_ns
        T_suit = self._suit_pose(suit_ns)
        if T_suit is None and self.take_waiting("suit odometry"):  # polled: taken at the drain's pace
            T_suit = self._suit_pose(suit_ns)
        if T_suit is None:
            return None
        if not np.isfinite(self._odometry_tilt_deg):
            self._check_odometry_axes(suit_ns, T_suit[:3, :3])
        if self._odometry_axes is not None:  # read in the pelvis segment's axes
            T_suit[:3, :3] = T_suit[:3, :3] @ self._odometry_axes
        suit = self.body.pose(suit_ns, T_suit)[0]
        return None if suit is None else (T_suit, suit)

    def _check_odometry_axes(self, suit_ns: int, R_odometry: np.ndarray) -> None:
        """Once per capture, at the first frame with both: the suit odometry's orientation against its pelvis
        segment's (:func:`~lip_ros.hsc4d.suit_track.odometry_axes`, as the trajectory node does): an odometry in
        other axes (a ROS base_link's, say) is read in the segment's from then on, so that its feet stand where the
        suit's do."""
        R_I_P = self.body.pelvis_rotation(suit_ns)
        if R_I_P is None:
            return
        self._odometry_tilt_deg, self._odometry_axes = odometry_axes(R_odometry, R_I_P, _MAX_ODOMETRY_TILT_DEG)
        if self._odometry_tilt_deg > _MAX_ODOMETRY_TILT_DEG:
            self.get_logger().warning(f"suit odometry: {self._odometry_axes_status()}")

    def _odometry_axes_status(self) -> str:
        """How the suit odometry's orientation is read: in the pelvis segment's axes or in its own turned."""
        tilt = self._odometry_tilt_deg
        if not np.isfinite(tilt):
            checked = self._lock is not None or self._optimiser is not None  # else its pose is never needed
            return "not checked yet" if checked else "not checked (no foot lock, no optimisation)"
        if tilt <= _MAX_ODOMETRY_TILT_DEG:
            return "the pelvis segment's"
        said = f"its pelvis up {tilt:.0f} deg from the pelvis IMU's"
        if self._odometry_axes is None:
            return f"{said}, not a turn of the axes: its feet taken as they come (the foot lock and the optimisation)"
        return f"{said}: its axes taken for the segment's x, y, z: {axes_columns(self._odometry_axes)}"

    def _optimise_frame(self, fused: _FusedPose, pose: BodyPose, suit: tuple[np.ndarray, BodyPose] | None) -> None:
        """Give one posed frame to the optimiser (with the suit's own pelvis and feet, :meth:`_suit_own`); optimise
        a full window."""
        if suit is None:
            self._not_optimised["optimisation skipped: no suit odometry near the frame"] += 1
            return
        T_suit, suit_body = suit
        live = self._optimiser
        t_s, suit_feet = fused.line_ns * 1e-9, suit_body.joints[self._feet]
        dropped = live.add(_OptimisedFrame(fused.stamp_ns, fused.frame_id, pose, fused.T_map_P, t_s, suit_feet), t_s,
                           fused.T_map_P, *leg_chains(self.body.skeleton, pose.local_rot), T_suit[:3, 3], suit_feet)
        self._count_skipped(len(dropped), self._drop_reason(live))
        self._solve(live)

    @staticmethod
    def _waiting_reason(live: BackgroundOptimiser) -> str:
        """Why frames waited for the optimisation in vain: no map, or no ground under the first window's feet."""
        return "no map yet" if live.map is None else "no ground under the feet of the first window (no sole height)"

    def _drop_reason(self, live: BackgroundOptimiser) -> str:
        """Why frames were dropped for want of room: they waited in vain, or (the sole height known) the windows
        were solved slower than they came."""
        return self._waiting_reason(live) if live.sole_m is None else "the optimisation fell behind"

    def _skip(self, live: BackgroundOptimiser, reason: str) -> None:
        """Drop every frame waiting in ``live``, counted."""
        self._count_skipped(len(live.drop()), reason)

    def _count_skipped(self, n: int, reason: str) -> None:
        if n:
            self._not_optimised[f"optimisation skipped: {reason}"] += n
            self.get_logger().warning(f"{n} frames not optimised: {reason}")

    def _solve(self, live: BackgroundOptimiser, flush: bool = False) -> None:
        """Publish ``live``'s window solved, if one is, and start solving its next if a whole one waits (``flush``:
        a partial one too). Without a map, or before a map shows the ground under the first window's feet, they
        wait for a later map (up to the optimiser's capacity). The windows are solved on a thread of their own:
        the node goes on taking the suit's samples and posing meanwhile."""
        solved = live.collect()
        if solved is not None:
            if isinstance(solved.error, NoGroundYet):
                self.get_logger().info(f"optimisation waits for a later map: {solved.error}")
            elif solved.error is not None:  # a bug: the node goes on, the window's frames counted
                self.get_logger().error(f"optimisation failed: {''.join(format_exception(solved.error))}")
                self._count_skipped(len(solved.records), f"failed ({type(solved.error).__name__})")
            else:
                self._window_latency.add(solved.seconds)
                self._publish_optimised(solved.records, solved.result, self._optimised_locks.get(id(live)))
            self._count_skipped(len(solved.dropped), self._drop_reason(live))
        live.start(flush)

    def _publish_optimised(self, records: list[_OptimisedFrame], result: WindowResult, lock: FootLock | None) -> None:
        """The optimised pelvis and legs of the frames of ``records``: the body turned about its pelvis with it, on
        those legs, at the size the window was solved at (the legs' length from the walk), its standing feet held
        by ``lock`` (its optimiser's; None: not held)."""
        t, R, legs, leg_ratio = result.t, result.R, result.legs, result.leg_ratio
        for k, (stamp_ns, frame_id, pose, T, t_s, suit_feet) in enumerate(records):
            T_opt = np.eye(4)
            T_opt[:3, :3], T_opt[:3, 3] = R[k], t[k]
            moved = resized_body(bent_legs(moved_body(pose, T, T_opt), self.body.skeleton, legs[k]), leg_ratio)
            if lock is not None:
                moved = lock.step(t_s, moved, suit_feet)
            self._opt_odometry.publish(odometry_to_msg(self.backend, stamp_ns, frame_id, PELVIS_FRAME, t[k],
                                                       matrix_to_quat(R[k])))
            for topic, raw in pose_cdr(OPTIMISED_TOPICS, self.body.skeleton, stamp_ns, frame_id, moved.local_rot,
                                       moved.glob_rot, moved.joints).items():
                self._opt_out[topic].publish(raw)
        self._optimised += len(t)

    def _on_offset(self, msg: Int64) -> None:
        self._offset_ns = int(msg.data)
        if self._new_capture is not None:  # the new capture's (the trajectory sends it before its poses)
            self._new_capture = (self._new_capture[0], True)
        self._drain()

    def _on_imu(self, segment: str, data: bytes) -> int:
        """Keep a suit sample's bytes (decoded in a batch when a pose needs them) and its stamp."""
        stamp_ns = cdr_stamp(data)
        line_ns = self.on_time_line(self._suit_clock, segment, stamp_ns)
        raw = self._raw[segment]
        raw.append((data, line_ns - stamp_ns))
        if len(raw) > self.body.config.capacity:  # no pose asked for a while: keep the newest
            del raw[: len(raw) - self.body.config.capacity]
        self._newest[segment] = max(line_ns, self._newest.get(segment, line_ns))
        self._arrived[segment] = time.monotonic()
        return stamp_ns

    def _decode(self) -> None:
        """Decode and buffer every segment's samples received since the last time."""
        for segment, raw in self._raw.items():
            if not raw:
                continue
            samples = []
            for (data, shift_ns), sample in zip(raw, imu_samples([d for d, _ in raw]), strict=True):
                try:  # a message that is not plain little-endian CDR: deserialised and checked in full
                    sample = sample if sample is not None else msg_to_imu(deserialize_message(data, Imu))
                except (MalformedMessageError, RuntimeError) as exc:
                    self._rejected[str(exc).split(":")[0][:60]] += 1
                    continue
                samples.append(replace(sample, stamp_ns=sample.stamp_ns + shift_ns) if shift_ns else sample)
            for reason in self.body.add(segment, samples):
                if reason is not None:
                    self._rejected[reason] += 1
            raw.clear()

    def _on_odometry(self, msg: Odometry) -> int:
        self.take_waiting("suit odometry")  # polled: a new capture it shows is seen before this pose is placed
        odometry = msg_to_odometry(msg)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = quat_to_matrix(odometry.quat), odometry.position
        now = time.monotonic()
        new = self._new_capture
        if new is not None and (new[1] or stepped_back(odometry.stamp_ns, new[0])):
            line_ns = self._first_of_new_capture(odometry.stamp_ns)
        else:  # the trajectory node's output, in order: a step back in it is the LiDAR's clock stepping
            line_ns = self.on_time_line(self._lidar_clock, "fused odometry", odometry.stamp_ns, confirm=False)
        self._last_fused_ns = odometry.stamp_ns
        self._waiting.append(_FusedPose(odometry.stamp_ns, line_ns, odometry.frame_id, T, now,
                                        now + self.params["suit_wait_s"]))
        if len(self._waiting) > self.params["max_waiting_poses"]:
            self.take_polled()  # the oldest pose goes now, with every suit sample received (_drain takes them else)
        while len(self._waiting) > self.params["max_waiting_poses"]:
            self._pose(self._waiting.popleft())
        self._drain()
        return odometry.stamp_ns

    def _drain(self) -> None:
        """Take the suit's samples; pose the waiting fused poses they cover, or that waited long enough; optimise
        the last partial window once no pose came for ``optimise_flush_s``."""
        self.take_polled()
        now = time.monotonic()
        if self._optimiser is not None:
            live = self._optimiser
            flush = not self._waiting and now - self._last_pose_at >= self.params["optimise_flush_s"]
            self._solve(live, flush)
            if flush and len(live) and not live.busy:  # no map, or no ground under the first window's feet
                self._skip(live, self._waiting_reason(live))
            for last in list(self._closing):  # the last captures' windows, with what there is
                self._solve(last, flush=True)
                if not last.busy:
                    if len(last):  # no map, or no ground under its first window's feet
                        self._skip(last, f"a new capture began, {self._waiting_reason(last)}")
                    self._closing.remove(last)
                    closed = self._optimised_locks.pop(id(last), None)
                    self._optimised_released += 0 if closed is None else closed.released
        while self._waiting:
            fused = self._waiting[0]
            if self._offset_ns is not None:
                lagging = self._lagging(fused.line_ns + self._offset_ns)
                if lagging and (now < fused.deadline or (now < fused.received + SUIT_QUEUE_S
                                                         and self._sending(lagging, now))):
                    return
            elif now < fused.deadline:
                return
            self._pose(self._waiting.popleft())

    def _lagging(self, suit_ns: int) -> list[str]:
        """The segments that have not sent a sample at or after ``suit_ns`` yet."""
        return [s for s in self._raw if self._newest.get(s, suit_ns - 1) < suit_ns]

    def _sending(self, segments: list[str], now: float) -> bool:
        """Whether each of ``segments`` sent a sample within the last ``suit_wait_s`` (it is behind, not gone)."""
        return all(now - self._arrived.get(s, -np.inf) < self.params["suit_wait_s"] for s in segments)

    def _pose(self, fused: _FusedPose) -> None:
        """Pose and publish the body at one fused pelvis pose, or count why not."""
        stamp_ns, frame_id, T_map_P = fused.stamp_ns, fused.frame_id, fused.T_map_P
        if self._offset_ns is None:
            self.count_frame("skipped: no suit clock offset", f"{stamp_ns}: none received on "
                                                              f"{self.params['offset_topic']}")
            return
        if self._scale_from_height:
            self._scale_from_height, self._standing_m, self._fused_ratio = False, None, 1.0
            height, where = float(T_map_P[2, 3]), "the first fused pose's"
            resumed, self._resumed = self._resumed, None
            if resumed is not None and resume_refusal(resumed, stamp_ns, self.params["resume_max_gap_s"]) is None:
                height, where = resumed.pelvis_height_m, "the capture's start's (resume_file)"
            try:
                scale = self.body.scale_to_pelvis_height(height)
            except ValueError as exc:
                self.get_logger().warning(f"body left at {self.body.skeleton.scale:.3f} x the contract skeleton: "
                                          f"{exc}")
            else:
                self._standing_m = height
                self.get_logger().info(f"body scaled to {where} standing pelvis height {height:.3f} m: "
                                       f"{scale:.3f} x the contract skeleton")
        self._decode()
        pose, reason = self.body.pose(fused.line_ns + self._offset_ns, T_map_P)
        if pose is None:
            self.count_frame("skipped: suit data missing", f"{stamp_ns}: {reason}")
            return
        if reason:
            self._degraded += 1
            self.get_logger().info(f"pose at {stamp_ns} with held suit data: {reason}", throttle_duration_sec=2.0)
        fused_pose = self._walk_sized(pose)
        suit = self._suit_own(fused) if self._lock is not None or self._optimiser is not None else None
        if self._lock is not None:
            fused_pose = self._lock.step(fused.line_ns * 1e-9, fused_pose,
                                         None if suit is None else suit[1].joints[self._feet])
        for topic, raw in pose_cdr(HSC4D_TOPICS, self.body.skeleton, stamp_ns, frame_id, fused_pose.local_rot,
                                   fused_pose.glob_rot, fused_pose.joints).items():
            self._out[topic].publish(raw)
        self.count_frame("pose")
        self._latency.add(time.monotonic() - fused.received)
        if self._optimiser is not None:
            self._last_pose_at = time.monotonic()
            self._optimise_frame(fused, pose, suit)

    def _walk_sized(self, pose: BodyPose) -> BodyPose:
        """The fused body as published: with its size from the standing height, at the legs' length from the walk
        once the optimiser believes it (as it had it at its last window collected), about the fused pelvis; else
        ``pose``."""
        if self._standing_m is None or self._optimiser is None:
            return pose
        ratio = self._optimiser.leg_ratio
        if ratio != 1.0 and self._fused_ratio == 1.0:  # first believed (then each window's, on /diagnostics)
            self.get_logger().info(f"fused body at the legs' length from the walk: {ratio:.4f} x the standing "
                                   f"height's size; the standing pelvis stood {self._off_walk(ratio):+.3f} m off "
                                   f"those legs (the hip LiDAR's lever arm along the body off its nominal part, "
                                   f"or the soles)")
        self._fused_ratio = ratio
        return pose if ratio == 1.0 else resized_body(pose, ratio)

    def _off_walk_status(self) -> str:
        """:meth:`_off_walk` of the fused body's size now, or why there is none."""
        if self._optimiser is None:
            return "not measured (no optimisation)"
        if self._standing_m is None:
            return "not measured (body_scale given)"
        return "not measured yet" if self._fused_ratio == 1.0 else f"{self._off_walk(self._fused_ratio):+.3f}"

    def _off_walk(self, ratio: float) -> float:
        """How far the standing pelvis height the body was scaled to stands above the legs at ``ratio`` of it
        (positive: higher)."""
        return (1.0 - ratio) * self._standing_m

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """Poses published, the body's scale, poses waiting, latencies."""
        level = DiagnosticLevel.OK if self.frames["pose"] else DiagnosticLevel.WARN
        message = "posing" if self.frames["pose"] else "no pose yet"
        if self._odometry_tilt_deg > _MAX_ODOMETRY_TILT_DEG:
            level, message = DiagnosticLevel.WARN, f"{message}; suit odometry: {self._odometry_axes_status()}"
        return level, message, {
            "body scale": f"{self.body.skeleton.scale * self._fused_ratio:.3f}",
            "standing pelvis height off the walk's legs (m)": self._off_walk_status(),
            **self._lock_status(),
            "suit odometry's orientation read in": self._odometry_axes_status(),
            "poses with held suit data": self._degraded,
            "pending": len(self._waiting), **{f"suit samples rejected: {k}": v for k, v in self._rejected.items()},
            "clock steps back (LiDAR, suit)": f"{len(self._lidar_clock.steps_ns)}, {len(self._suit_clock.steps_ns)}",
            "new captures begun": self._began_again,
            **self._latency.values("latency_ms"), **self._optimisation_status()}

    def _lock_status(self) -> dict[str, Any]:
        """The foot lock's: which feet stand now, anchors let go."""
        if self._lock is None:
            return {"foot lock": "off"}
        standing = [side for side, held in zip(("left", "right"), self._lock.standing(), strict=True) if held]
        out = {"feet standing": ", ".join(standing) or "none", "foot anchors let go": self._lock.released}
        if self._optimised_locks:
            out["optimised: foot anchors let go"] = (self._optimised_released
                                                     + sum(lock.released for lock in self._optimised_locks.values()))
        return out

    def _optimisation_status(self) -> dict[str, Any]:
        """The optimisation's counts: frames optimised, waiting, not optimised by reason; the sole height; the
        optimised body's size (the legs' length from the walk); time."""
        if self._optimiser is None:
            return {"optimisation": "off"}
        sole, ratio = self._optimiser.sole_m, self._optimiser.leg_ratio
        waiting = len(self._optimiser) + sum(len(last) for last in self._closing)
        return {"optimisation: frames optimised": self._optimised, OPTIMISING_VALUE: waiting,
                "optimisation: sole height (m)": "unknown" if sole is None else f"{sole:.3f}",
                "optimisation: body scale (legs from the walk)": f"{self.body.skeleton.scale * ratio:.3f}",
                **dict(self._not_optimised), **self._window_latency.values("optimisation_ms")}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros hsc4d_body_node``."""
    return run_nodes(BodyNode.NAME, __doc__.split("\n\n")[0], [BodyNode], [BodyNode], argv)


if __name__ == "__main__":
    raise SystemExit(main())
