"""pose_node: the LIP network (pose prior, joint map, body pose, pose-guided translation) and the pose outputs.

Joins the performer's points (``segmentation_node``) and the four calibrated
bone Imu messages (``calibration_node``) by exact stamp, runs the streaming
LIP network (:class:`lip_ros.lip.stages.PoseStage`) and publishes
``/lip/joint_states``, ``/lip/root_pose``, ``/lip/joint_poses`` and
``/lip/skeleton`` (reliable), all with that stamp: the moment the performer
was scanned. Where tf2_msgs is installed (a full ROS install), the pelvis is
also broadcast on /tf (``frame_id`` -> ``tf_child_frame``, the URDF's root
link) for robot_state_publisher and RViz; without it the node says so once
and goes on. With ``hri_body_id`` set, the ROS4HRI view (REP-155) too: the
same joint states on ``/humans/bodies/<id>/joint_states`` and the pelvis on
/tf as ``body_<id>`` (the ``/humans/bodies/tracked`` list needs hri_msgs,
which is not installed here: not published).

The translation corrector stays in this node with the pose network: it runs
in the same forward pass, on the network's raw (unnormalised) 6D rotations
and refined joint map, which no standard message carries exactly.
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import numpy as np
from sensor_msgs.msg import Imu, PointCloud2

from lip_msgs_py import (
    DiagnosticLevel,
    cloud_to_xyz,
    rclpy_message_class,
    read_header,
    tf_message,
    transform_stamped_to_msg,
)
from lip_ros.core.exact_sync import ExactTimeJoiner, Incomplete
from lip_ros.core.rotations import matrix_to_quat, quat_to_matrix
from lip_ros.core.torch_runtime import set_threads
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.sensors import IMU_NAMES, LIP_TOPICS
from lip_ros.lip.stages import Outcome, PoseStage
from lip_ros.lip.surface_fit import SURFACE_FIT
from lip_ros.nodes.base import (
    DIRECT_INPUTS_PARAM,
    RELIABLE,
    FrameArrivals,
    GraphNode,
    LatencyWindow,
    Param,
    ParameterError,
    positive,
    read_imu,
    run_nodes,
    tf_publisher,
)
from lip_ros.nodes.lip import LIP_PARAMS_FILE
from lip_ros.nodes.lip.calibration import CalibrationNode
from lip_ros.nodes.lip.ground import GROUND_PARAM, subscribe_ground
from lip_ros.outputs import pose_cdr

__all__ = ["PoseNode", "main"]


def _ros_name(value: Any) -> str | None:
    """Check: '' or a name usable in a topic and a frame (letters, digits, underscores; not starting with a digit)."""
    ok = value == "" or (isinstance(value, str) and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", value) is not None)
    return None if ok else f"must be letters, digits and underscores, not starting with a digit; got {value!r}"

_POINTS = "points"


class PoseNode(GraphNode):
    """The pose stage of the graph: exact-stamp join, LIP network, pose outputs (and /tf where available)."""

    NAME = "pose_node"
    PARAMS_FILE = LIP_PARAMS_FILE
    PARAMS = {
        "performer_topic": Param("input: the performer's points of segmentation_node"),
        "bone_topics": CalibrationNode.PARAMS["bone_topics"],
        "direct_inputs": DIRECT_INPUTS_PARAM,
        "weights": Param("LIP weights <path>.pt + <path>.json ('' = the shipped ones)"),
        "surface_fit": Param("fit the translation and the performer's shape to the points (false: the network's "
                             "translation; docs/lip/transfer.md)"),
        "frame_id": Param("frame of the outputs ('' = the LiDAR cloud's frame)"),
        "publish_tf": Param("broadcast the pelvis on /tf (needs tf2_msgs)"),
        "tf_child_frame": Param("child frame of the /tf pelvis transform (the URDF's root link)"),
        "hri_body_id": Param("ROS4HRI (REP-155) body id: also /humans/bodies/<id>/joint_states and the pelvis on /tf "
                             "as body_<id> ('' = off)", _ros_name),
        "ground_topic": GROUND_PARAM,
        "max_pose_gap_s": Param("after this long without a pose the network starts a new sequence", positive),
        "join_max_stamps": Param("stamps that may wait for the rest of their inputs", positive),
        "torch_threads": Param("torch's CPU threads for the network (process-wide; 1: no waiting on a core another "
                               "process holds, docs/lip/graph.md)", positive),
    }

    def __init__(self, arrivals: FrameArrivals | None = None, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        p = self.params
        set_threads(p["torch_threads"])
        try:
            model = LipModel.load(Path(p["weights"]).expanduser() if p["weights"] else None,
                                  surface_fit=SURFACE_FIT if p["surface_fit"] else None,
                                  lidar_rate_hz=p["lidar_rate_hz"])
        except (OSError, ValueError, KeyError, RuntimeError) as exc:
            raise ParameterError(f"cannot load weights {p['weights'] or '(shipped)'}: {exc}") from exc
        self.stage = PoseStage(model, max_gap_ns=int(p["max_pose_gap_s"] * 1e9))
        self._interleave = 1  # the interleave logged last (1: nothing to say)
        self._say_interleave("lidar_rate_hz", p["lidar_rate_hz"])
        self._arrivals = arrivals
        self._latency = LatencyWindow()  # last input of a frame -> its outputs published
        self._graph_latency = LatencyWindow()  # cloud received by segmentation_node (same process) -> published
        self._joiner = ExactTimeJoiner((_POINTS, *IMU_NAMES), p["join_max_stamps"])
        self._without_bones = 0  # performer clouds whose frame ended upstream (calibrating, skipped)
        self._out = {topic: self.create_publisher(rclpy_message_class(msgtype), topic, RELIABLE)
                     for topic, msgtype in ((LIP_TOPICS.joint_states, "sensor_msgs/msg/JointState"),
                                            (LIP_TOPICS.root_pose, "geometry_msgs/msg/PoseStamped"),
                                            (LIP_TOPICS.joint_poses, "geometry_msgs/msg/PoseArray"),
                                            (LIP_TOPICS.skeleton, "visualization_msgs/msg/MarkerArray"))}
        body = p["hri_body_id"]  # ROS4HRI: the joint states again under the body's id, its TF root body_<id>
        self._hri_frame = f"body_{body}" if body else ""
        self._hri_pub = self.create_publisher(rclpy_message_class("sensor_msgs/msg/JointState"),
                                              f"/humans/bodies/{body}/joint_states", RELIABLE) if body else None
        self._tf_pub = tf_publisher(self) if p["publish_tf"] or body else None
        subscribe_ground(self, p["ground_topic"], self._on_ground)
        self.add_input("performer", p["performer_topic"], PointCloud2, p["lidar_rate_hz"],
                       lambda msg: self._on_input(_POINTS, msg), from_graph=True)
        for name, topic in zip(IMU_NAMES, p["bone_topics"]):  # raw: calibration_node publishes their CDR bytes
            self.add_input(f"bone {name}", topic, Imu, p["lidar_rate_hz"],
                           lambda data, name=name: self._on_input(name, data), raw=True, from_graph=True)
        self.get_logger().info(f"ready; weights {p['weights'] or '(shipped)'}")

    def _say_interleave(self, source: str, rate_hz: float | None = None) -> None:
        """Log how the network is fed frames at ``rate_hz`` (from ``source``; None: the rate the frames' stamps
        show) when that changes."""
        model = self.stage.model
        if model.interleave == self._interleave:
            return
        self._interleave = model.interleave
        rate_hz = rate_hz if rate_hz is not None else round(self.stage.period.rate_hz or 0.0, 1)
        self.get_logger().info(f"the network learned motion at {model.config.rate_hz:g} Hz: the {rate_hz:g} Hz "
                               f"frames ({source}) are fed to it as {model.interleave} interleaved sequence"
                               f"{'s' if model.interleave > 1 else ''}")

    def _on_ground(self, level: np.ndarray) -> None:
        self.stage.level = level

    def _on_input(self, name: str, msg: Any) -> int:
        """A performer cloud (message) or a bone (Imu CDR bytes) of a frame; the frame's pose once it has all."""
        if name == _POINTS:
            stamp_ns, frame_id = read_header(msg)
            item = (cloud_to_xyz(msg), frame_id)
        else:
            sample = read_imu(msg)
            stamp_ns, item = sample.stamp_ns, (quat_to_matrix(sample.quat), sample.accel)
        done, dropped = self._joiner.add(name, stamp_ns, item)
        for incomplete in dropped:
            self._give_up(incomplete)
        for items in done:
            self._estimate(stamp_ns, items)
        return stamp_ns

    def _give_up(self, incomplete: Incomplete) -> None:
        if set(incomplete.items) == {_POINTS}:
            self._without_bones += 1  # no pose for this frame upstream: calibration_node accounted for it
            return
        missing = ", ".join(incomplete.missing(self._joiner.names))
        self.count_frame("skipped: inputs incomplete", f"{incomplete.stamp_ns}: no {missing} with this stamp")

    def _estimate(self, stamp_ns: int, items: dict[str, Any]) -> None:
        start = time.monotonic()
        points, cloud_frame = items[_POINTS]
        rot = np.stack([items[n][0] for n in IMU_NAMES])
        acc = np.stack([items[n][1] for n in IMU_NAMES])
        pose, _, _ = self.stage.estimate(stamp_ns, points, rot, acc)
        self._say_interleave("measured from their stamps")  # where the stage set the model for the measured rate
        frame_id = self.params["frame_id"] or cloud_frame
        messages = pose_cdr(LIP_TOPICS, self.stage.skeleton, stamp_ns, frame_id, pose.local_rot, pose.glob_rot,
                            pose.joint_pos)
        for topic, raw in messages.items():
            self._out[topic].publish(raw)
        if self._hri_pub is not None:
            self._hri_pub.publish(messages[LIP_TOPICS.joint_states])
        if self._tf_pub is not None:
            children = [self.params["tf_child_frame"]] if self.params["publish_tf"] else []
            children += [self._hri_frame] if self._hri_frame else []
            quat = matrix_to_quat(pose.glob_rot[0])
            self._tf_pub.publish(tf_message(self.backend, [
                transform_stamped_to_msg(self.backend, stamp_ns, frame_id, child, pose.root_pos, quat)
                for child in children]))
        self.count_frame(Outcome.POSE.value)
        now = time.monotonic()
        self._latency.add(now - start)
        received = self._arrivals.pop(stamp_ns) if self._arrivals is not None else None
        if received is not None:
            self._graph_latency.add(now - received)

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """Poses published, sequences started, inputs waiting, latencies."""
        level = DiagnosticLevel.OK if self.frames[Outcome.POSE.value] else DiagnosticLevel.WARN
        message = "estimating" if level == DiagnosticLevel.OK else "no pose yet"
        return level, message, {"sequences": self.stage.sequences, "interleaved sequences": self._interleave,
                                "waiting stamps": self._joiner.open_stamps,
                                "performer clouds without bones": self._without_bones,
                                **{f"performer {k}": v for k, v in self.stage.model.performer_shape.items()},
                                **self._latency.values("latency_ms"),
                                **self._graph_latency.values("graph_latency_ms")}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros pose_node``."""
    return run_nodes(PoseNode.NAME, __doc__.split("\n\n")[0], [PoseNode], [PoseNode], argv)


if __name__ == "__main__":
    raise SystemExit(main())
