"""Record a synthetic HSC4D capture as a rosbag2 MCAP bag with the contract's topics and ground-truth sidecars.

Topics: ``/hip/points`` (PointCloud2, Ouster ``original``, frame ``hip_lidar``),
``/mocap/<segment>/imu`` (Imu, 17 segments, the suit's clock),
``/mocap/odometry`` (Odometry, ``mocap_world``, the suit's clock), and the
ground truth ``/gt/root_pose``, ``/gt/joint_poses``, ``/gt/joint_states`` in
the site's world frame ``world`` at the middle of each sweep (LiDAR clock).
Messages are logged when a recorder on the LiDAR's clock would receive them:
a cloud when its sweep ends, a suit sample a few ms after its measurement.

Sidecars (ignored by ``ros2 bag``): ``rig_truth.yaml`` (configuration, the
site's layout, the LiDAR's true mounting, the suit's heading, clock offset
and odometry errors, phases) and ``site_truth.npz`` (the performer at 100 Hz:
stamps on the LiDAR clock, pelvis, joints, rotations, the LiDAR's pose, the
planted feet).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lip_msgs_py import RosbagsBackend, array_to_cloud, imu_to_msg, odometry_to_msg
from lip_ros.bagio import mcap_writer
from lip_ros.core.rotations import matrix_to_quat
from lip_ros.hsc4d.sensors import HIP_LIDAR_TOPIC, SUIT_ODOMETRY_TOPIC
from lip_ros.outputs import GT_TOPICS, pose_messages
from lip_ros.rig.bag import TRUTH_FILE, LogOrderWriter, Progress
from lip_ros.rig.site_capture import SiteCapture

__all__ = ["write_site_bag", "SITE_TRUTH_FILE", "HIP_LIDAR_TOPIC", "HIP_LIDAR_FRAME", "SUIT_ODOMETRY_TOPIC",
           "WORLD_FRAME"]

SITE_TRUTH_FILE = "site_truth.npz"
HIP_LIDAR_FRAME = "hip_lidar"
SUIT_WORLD_FRAME = "mocap_world"
WORLD_FRAME = "world"  # the site's frame W, of the ground truth only
SUIT_LATENCY_NS = 5_000_000  # the suit's wireless delivery
CLOUD_LATENCY_NS = 2_000_000  # driver time after the sweep ends


def _truth_sidecar(capture: SiteCapture) -> dict[str, Any]:
    m, mount, suit = capture.motion, capture.mount, capture.suit
    return {
        "generator": "lip_ros.rig (HSC4D)",
        "config": capture.config.as_dict(),
        "epoch_ns": capture.epoch_ns,
        "site": {key: np.asarray(v).tolist() for key, v in capture.terrain.layout.items()},
        "lidar": {"frame_id": HIP_LIDAR_FRAME, "beams": capture.lidar.beams, "columns": capture.lidar.columns,
                  "rate_hz": capture.lidar.rate_hz, "lever_m": mount.lever_m.tolist(),
                  "tilt_up_deg": float(mount.tilt_up_deg), "R_M_L": mount.R_M_L.tolist()},
        "performer": {"body_scale": m.skeleton.scale, "girth": capture.body.girth},
        "suit": {"psi": float(suit.psi), "clock_offset_s": float(suit.clock_offset_s)},
        "phases": [{"name": n, "start_ns": a, "end_ns": b} for n, a, b in capture.phases_ns()],
    }


def write_site_bag(capture: SiteCapture, out: Path, progress: bool = True) -> dict[str, int]:
    """Simulate ``capture`` and record it to the bag directory ``out`` (must not exist); message counts per
    topic."""
    out = Path(out)
    backend = RosbagsBackend()
    skeleton = capture.motion.skeleton
    offset_ns = int(round(capture.suit.clock_offset_s * 1e9))
    odometry = capture.suit_odometry()
    period = capture.lidar.period_ns
    report = Progress(capture.num_frames, f"lip_rig {out.name}", progress)
    with mcap_writer(out, zstd=True) as writer:
        log = LogOrderWriter(writer, backend)
        for s in capture.suit_streams().values():
            for sample in s.samples(f"mocap_{s.name}"):  # received on the LiDAR's clock
                log.push(sample.stamp_ns - offset_ns + SUIT_LATENCY_NS, s.topic, imu_to_msg(backend, sample),
                         "sensor_msgs/msg/Imu")
        for k in range(len(odometry.stamp_ns)):
            stamp = int(odometry.stamp_ns[k])
            msg = odometry_to_msg(backend, stamp, SUIT_WORLD_FRAME, "mocap_pelvis", odometry.position[k],
                                  odometry.quat[k], odometry.velocity[k])
            log.push(stamp - offset_ns + SUIT_LATENCY_NS, SUIT_ODOMETRY_TOPIC, msg, "nav_msgs/msg/Odometry")
        for k, frame in capture.frames():
            stamp = frame.stamp_ns
            cloud = array_to_cloud(backend, frame.points, stamp, HIP_LIDAR_FRAME)
            log.push(stamp + period + CLOUD_LATENCY_NS, HIP_LIDAR_TOPIC, cloud, "sensor_msgs/msg/PointCloud2")
            mid = stamp + period // 2
            gt = capture.truth(np.array([(mid - capture.epoch_ns) * 1e-9]))
            for topic, (msgtype, msg) in pose_messages(backend, GT_TOPICS, skeleton, mid, WORLD_FRAME,
                                                       gt.local_rot[0], gt.glob_rot[0], gt.joints[0]).items():
                log.push(mid, topic, msg, msgtype)
            log.flush(stamp + period)
            report(k + 1)
        log.flush()
    truth = capture.truth()
    np.savez_compressed(
        out / SITE_TRUTH_FILE,
        stamp_ns=capture.epoch_ns + np.rint(truth.t * 1e9).astype(np.int64),
        pelvis=truth.pelvis,
        pelvis_quat=matrix_to_quat(truth.R_W_M),
        joints=truth.joints.astype(np.float32),
        joint_quats=matrix_to_quat(truth.glob_rot).astype(np.float32),
        lidar_position=truth.p_W_L,
        lidar_quat=matrix_to_quat(truth.R_W_L),
        stance_weight=truth.contacts.weight.astype(np.float32),
        stance_anchor=truth.contacts.anchor.astype(np.float32),
    )
    with open(out / TRUTH_FILE, "w", encoding="utf-8") as f:
        yaml.safe_dump(_truth_sidecar(capture), f, sort_keys=False)
    return log.counts
