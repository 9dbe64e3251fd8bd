"""calibration_node: IMU synchronisation and the A/T-pose calibration; calibrated bone inertia out.

Subscribes to the four DOTs (SensorDataQoS; their samples are taken every
``POLL_PERIOD_S`` and as each performer frame comes in, not one executor
wake-up each: ``GraphNode.add_input(polled=True)``) and the performer's points of
``segmentation_node`` (reliable). For each performer frame, once the DOTs
cover its pose time, it either feeds the automatic A-pose / T-pose
calibration or publishes, per sensor, the bone's orientation R_L_B and free
acceleration (gravity removed) in the LiDAR frame at the pose time: a
``sensor_msgs/Imu`` on ``bone_topics`` (reliable) with the performer cloud's
stamp and frame id, angular velocity marked not provided (REP-145
covariance[0] = -1). ``pose_node`` joins them with the points by exact stamp.
One DOT silent for up to ``max_silent_dot_s``: the frame is still posed, that
bone held (``lip_ros.lip.stages.ImuStage``) and published with its linear
acceleration not provided, a WARN on ``/diagnostics`` while it lasts.

Calibration: automatic at start (or loaded from ``calibration_file``, which
every solved calibration is written to, so a restarted node resumes), and on
request through std_srvs/Trigger services ``lip/start_calibration`` (look for
a new A/T-pose; the current calibration stays in use until it is solved) and
``lip/reset_calibration`` (forget it and its file, look for a new one). The
state is published latched (reliable, transient local) on ``calibration_topic``
as a std_msgs/String holding YAML: state, status line, the calibration (the
``calibration_file`` layout) and the file.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from sensor_msgs.msg import Imu, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from lip_msgs_py import (
    DiagnosticLevel,
    MalformedMessageError,
    cloud_to_xyz,
    imu_sample,
    read_header,
)
from lip_msgs_py.cdr_writer import imu_cdr
from lip_ros.core.imu_sync import SyncConfig
from lip_ros.core.rotations import matrix_to_quat
from lip_ros.core.sensor_monitor import odd_delays
from lip_ros.lip.calibration import CalibrationError
from lip_ros.lip.dot_latency import LatencyConfig
from lip_ros.lip.sensors import IMU_NAMES
from lip_ros.lip.stages import CLOCKS_REASON, BoneFrame, ImuStage, Outcome
from lip_ros.nodes.base import (
    DIRECT_INPUTS_PARAM,
    IMU_INPUT,
    LATCHED,
    POLL_PERIOD_S,
    GraphNode,
    LatencyWindow,
    Param,
    ParameterError,
    non_negative,
    numbers,
    positive,
    read_imu,
    run_nodes,
)
from lip_ros.nodes.lip import CALIBRATION_NODE_NAME, DOT_LATENCY_VALUE, LIP_PARAMS_FILE
from lip_ros.nodes.lip.ground import GROUND_PARAM, subscribe_ground

__all__ = ["CalibrationNode", "main", "DOT_LATENCY_VALUE", "DOT_STAMP_SPREAD_S"]

#: DOTs stamped on arrival at one host agree on receive time less stamp; one this much off the others' is a WARN.
DOT_STAMP_SPREAD_S = 0.025


def _four_topics(value: Any) -> str | None:
    return None if len(value) == len(IMU_NAMES) else (
        f"needs {len(IMU_NAMES)} topics, in the order {', '.join(IMU_NAMES)}; got {len(value)}")


def _latencies(value: Any) -> str | None:
    problem = numbers(0, len(IMU_NAMES))(value)
    if problem is None and any(v < 0 for v in value):
        problem = f"must not be negative, got {value!r}"
    return problem


class CalibrationNode(GraphNode):
    """The IMU stage of the graph: synchronisation, calibration, calibrated bone orientations and accelerations."""

    NAME = CALIBRATION_NODE_NAME
    PARAMS_FILE = LIP_PARAMS_FILE
    PARAMS = {
        "imu_topics": Param("the four DOT Imu inputs, in the order " + ", ".join(IMU_NAMES), _four_topics),
        "imu_rate_hz": Param("expected DOT rate", positive),
        "performer_topic": Param("input: the performer's points of segmentation_node"),
        "bone_topics": Param("outputs: calibrated bone orientation and free acceleration in L, order as imu_topics",
                             _four_topics),
        "calibration_topic": Param("output (latched): the calibration state as YAML"),
        "direct_inputs": DIRECT_INPUTS_PARAM,
        "ground_topic": GROUND_PARAM,
        "heading_reset_service": Param("the DOT driver's std_srvs/Trigger service that resets the four DOTs' "
                                       "headings together, called whenever a calibration starts ('' = none)"),
        "calibration_file": Param("calibration YAML: loaded at start if present, written when solved ('' = none)"),
        "max_imu_gap_s": Param("widest gap between two samples of a DOT that is interpolated across", positive),
        "max_imu_hold_s": Param("oldest a DOT sample may be when held for a frame it does not cover", positive),
        "imu_wait_s": Param("how long a frame waits for late DOT data after its pose time", positive),
        "max_pending_frames": Param("frames that may wait for DOT data; older ones are skipped", positive),
        "max_silent_dot_s": Param("one DOT silent up to this long: the frames are posed with its bone held, turned "
                                  "with the performer (0: skipped)", non_negative),
        "max_clock_gap_s": Param("a frame stamped this far outside the buffered DOT samples is on another clock: "
                                 "skipped, ERROR on /diagnostics", positive),
        "dot_latency_s": Param("per DOT, order as imu_topics: how much later than measured its driver stamps a sample "
                               "(on arrival over Bluetooth: tens of ms), taken off every stamp ([] = none)",
                               _latencies, any_type=True),
        "estimate_dot_latency": Param("estimate each DOT's latency online from the limbs the LiDAR sees moving, and "
                                      "take it off instead of dot_latency_s once found (docs/conventions.md)"),
    }

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        p = self.params
        file = Path(p["calibration_file"]).expanduser() if p["calibration_file"] else None
        sync = SyncConfig(max_gap_ns=int(p["max_imu_gap_s"] * 1e9), max_hold_ns=int(p["max_imu_hold_s"] * 1e9),
                          wait_ns=int(p["imu_wait_s"] * 1e9), max_clock_gap_ns=int(p["max_clock_gap_s"] * 1e9),
                          latency_ns=tuple(round(v * 1e9) for v in p["dot_latency_s"]))
        try:
            self.stage = ImuStage(sync, calibration_file=file, max_pending=p["max_pending_frames"],
                                  latency=LatencyConfig(enabled=p["estimate_dot_latency"]),
                                  max_silent_ns=round(p["max_silent_dot_s"] * 1e9))
        except (OSError, ValueError, KeyError, CalibrationError) as exc:
            raise ParameterError(f"cannot load calibration_file {file}: {exc}") from exc
        self._latency = LatencyWindow()
        self._estimated: dict[str, int | None] = dict.fromkeys(IMU_NAMES)  # the latency estimates last logged
        self._bone_pubs = [self.create_between_publisher(Imu, topic) for topic in p["bone_topics"]]
        self._state_pub = self.create_publisher(String, p["calibration_topic"], LATCHED)
        self._published_state: tuple[int, bool] | None = None
        self._held = 0  # frames published with a held (not interpolated) sample of some DOT
        self._held_bones: Counter[str] = Counter()  # per DOT: frames posed with its bone held (the DOT silent)
        self._held_bones_reported: Counter[str] = Counter()
        self._clock_steps = 0  # clock steps of the frames and the DOTs logged so far
        self._last_sync = "no frame yet"
        for name, topic in zip(IMU_NAMES, p["imu_topics"]):  # polled: no executor wake-up per sample
            self.add_input(name, topic, Imu, p["imu_rate_hz"], lambda data, name=name: self._on_imu(name, data),
                           IMU_INPUT, raw=True, polled=True, stamped_at=0.0)
        self.create_timer(POLL_PERIOD_S, self.take_polled, self.group, clock=self.steady)
        self.add_input("performer", p["performer_topic"], PointCloud2, p["lidar_rate_hz"],
                       self._on_performer, from_graph=True)
        subscribe_ground(self, p["ground_topic"], self._on_ground)
        self.create_service(Trigger, "lip/start_calibration", self._on_start, callback_group=self.group)
        self.create_service(Trigger, "lip/reset_calibration", self._on_reset, callback_group=self.group)
        self._heading_reset = "not configured"
        self._heading_reset_wanted = False
        self._heading_client = None
        if p["heading_reset_service"]:
            self._heading_client = self.create_client(Trigger, p["heading_reset_service"], callback_group=self.group)
            self._heading_reset_wanted = self.stage.calibrating
            self.create_timer(0.5, self._reset_headings, self.group, clock=self.steady)
        self._publish_state()
        self.get_logger().info(f"ready; {self.stage.status}")

    def _on_ground(self, level: np.ndarray) -> None:
        self.stage.level = level

    def _on_imu(self, name: str, data: bytes) -> int:
        sample = read_imu(data)
        reason = self.stage.add_imu(name, sample)
        if reason is not None:
            raise MalformedMessageError(reason)
        self._publish(self.stage.poll())
        return sample.stamp_ns

    def _on_performer(self, msg: PointCloud2) -> int:
        stamp_ns, frame_id = read_header(msg)
        points = cloud_to_xyz(msg)
        self.take_polled()  # the DOT samples received so far first, as if each had been taken on arrival
        self._publish(self.stage.add_frame(stamp_ns, stamp_ns, points, (frame_id, time.monotonic())))
        self._publish(self.stage.poll())
        return stamp_ns

    def _publish(self, frames: list[BoneFrame]) -> None:
        for f in frames:
            if f.outcome == Outcome.POSE:
                frame_id, received = f.tag
                quats = matrix_to_quat(f.bone_rot)
                held = f.held
                bones = [imu_cdr(imu_sample(f.pose_stamp_ns, frame_id, quat=q, accel=None if h else acc))  # held:
                         for q, acc, h in zip(quats, f.free_acc, held)]  # its acceleration not provided
                self._latency.add(time.monotonic() - received)  # before the publication (see segmentation_node)
                for pub, bone in zip(self._bone_pubs, bones):
                    pub.publish(bone)
                self._held += bool(f.reason)
                self._held_bones.update(n for n, h in zip(IMU_NAMES, held) if h)
                self._last_sync = f.reason or "all DOTs interpolated"
            elif f.outcome == Outcome.CALIBRATING:
                self.count_frame(Outcome.CALIBRATING.value)
            else:
                self.count_frame(f"skipped: {f.reason.split(':')[0]}", f"{f.pose_stamp_ns}: {f.reason}")
                self._last_sync = f.reason
                if f.reason.startswith(CLOCKS_REASON):
                    self.get_logger().error(f.reason, throttle_duration_sec=5.0)
        self.stage.score_latency()  # the DOT latency estimate's work, after the bones are out
        steps = self.stage.clock_steps + sum(self.stage.sync.clock_steps.values())
        if steps > self._clock_steps:
            self._clock_steps = steps
            self.get_logger().warning(f"stamps stepped back (a clock step, or a bag played again): DOT buffers and "
                                      f"waiting frames started again, the calibration kept; steps so far: "
                                      f"frames {self.stage.clock_steps}, DOTs {self.stage.sync.clock_steps}")
        if frames:
            self._publish_state()
            self._log_latency()

    def _log_latency(self) -> None:
        """Say when a DOT's latency estimate changed."""
        if self.stage.latency is None or self.stage.latency.estimate_ns == self._estimated:
            return
        self._estimated = dict(self.stage.latency.estimate_ns)
        self.get_logger().info(f"DOT latencies taken off (ms): {self.stage.latency_status}")

    def _publish_state(self) -> None:
        """The calibration state on the latched topic, when it changed."""
        state = (self.stage.calibration_count, self.stage.calibrating)
        if state == self._published_state:
            return
        self._published_state = state
        cal = self.stage.calibration
        doc = {"state": ("recalibrating" if cal is not None else "calibrating") if self.stage.calibrating
               else "calibrated",
               "status": self.stage.status,
               "calibration": None if cal is None else cal.as_dict(),
               "file": None if self.stage.calibration_file is None else str(self.stage.calibration_file)}
        self._state_pub.publish(String(data=yaml.safe_dump(doc, sort_keys=False)))
        if cal is not None and not self.stage.calibrating:
            where = f", saved to {self.stage.calibration_file}" if self.stage.calibration_file else ""
            self.get_logger().info(f"{self.stage.status}{where}")

    def _reset_headings(self) -> None:
        """Ask the DOT driver to reset the DOTs' headings together, once per calibration started, when it is up."""
        if not self._heading_reset_wanted:
            return
        name = self._heading_client.srv_name
        if not self._heading_client.service_is_ready():
            self._heading_reset = f"waiting for {name}"
            return
        self._heading_reset_wanted = False
        self._heading_reset = f"requested from {name}"
        self._heading_client.call_async(Trigger.Request()).add_done_callback(self._on_headings_reset)

    def _on_headings_reset(self, future: Any) -> None:
        result = future.result()
        if result is not None and result.success:
            self._heading_reset = f"done: {result.message}" if result.message else "done"
            self.get_logger().info(f"DOT headings reset ({self._heading_client.srv_name}); hold the A-pose, then "
                                   "the T-pose")
        else:
            self._heading_reset = f"failed: {'no answer' if result is None else result.message}"
            self.get_logger().warning(f"DOT heading reset {self._heading_reset}")

    def _on_start(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.stage.start_calibration()
        self._heading_reset_wanted = self._heading_client is not None
        self._publish_state()
        response.success, response.message = True, "hold the A-pose, then the T-pose, still, facing the LiDAR"
        self.get_logger().info(f"calibration requested: {response.message}")
        return response

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.stage.reset()
        self._heading_reset_wanted = self._heading_client is not None
        self._publish_state()
        response.success, response.message = True, "calibration forgotten; looking for the A-pose and T-pose"
        self.get_logger().info(response.message)
        return response

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """Calibration state, sync health, frames waiting for DOT data, latency performer cloud -> bones published."""
        level = DiagnosticLevel.OK if self.stage.calibrated else DiagnosticLevel.WARN
        message = self.stage.status
        odd = odd_delays({n: self.input_delay_s(n) for n in IMU_NAMES}, DOT_STAMP_SPREAD_S)
        if odd:  # the pose is interpolated at the wrong time for that DOT
            level = max(level, DiagnosticLevel.WARN)
            message = "; ".join([message, *(f"{n} stamped {abs(1e3 * d):.0f} ms {'ahead of' if d < 0 else 'behind'} "
                                           "the other DOTs (against their arrival)" for n, d in odd.items())])
        held = self._held_bones - self._held_bones_reported  # called once a report
        self._held_bones_reported = Counter(self._held_bones)
        if held:
            level = max(level, DiagnosticLevel.WARN)
            message = "; ".join([message, "since the last report posed with a silent DOT's bone held: " + ", ".join(
                f"{n} x{c}" for n, c in sorted(held.items()))])
        if self._last_sync.startswith(CLOCKS_REASON):  # nothing can come out until the clocks agree
            level, message = DiagnosticLevel.ERROR, self._last_sync
        return level, message, {"calibration": "calibrated" if self.stage.calibrated else "none",
                                          "pending": self.stage.pending, "bones with a held DOT sample": self._held,
                                          **{f"{n}'s bone held (frames)": c for n, c in self._held_bones.items()},
                                          "samples held for the calibration": self.stage.calibration_samples,
                                          "DOT heading reset": self._heading_reset,
                                          DOT_LATENCY_VALUE: self.stage.latency_status,
                                          "DOT headings": "unknown" if self.stage.calibration is None
                                          else self.stage.calibration.headings,
                                          "last sync": self._last_sync, "clock steps": self._clock_steps,
                                          **self._latency.values("latency_ms")}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros calibration_node``."""
    return run_nodes(CalibrationNode.NAME, __doc__.split("\n\n")[0], [CalibrationNode], [CalibrationNode], argv)


if __name__ == "__main__":
    raise SystemExit(main())
