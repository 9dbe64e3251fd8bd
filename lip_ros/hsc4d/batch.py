"""An HSC4D bag through the offline refinement, and the refinement as messages (ROS-free).

:func:`refine_bag` plays a bag's hip LiDAR, suit segments and suit odometry,
in the order they were logged, into a
:class:`~lip_ros.hsc4d.refinement.CaptureRefiner` and refines the capture;
malformed messages are counted and left out, as the nodes do. A bag that plays
a capture again (a loop recorded, or a new capture on the same sensors: the
nodes' rule, :class:`~lip_ros.hsc4d.suit_restart.SuitRestart`) is refined up
to where the next capture begins; the sweeps after are counted.
:func:`refinement_messages` gives the result as the ``/hsc4d/refined/*``
messages (:data:`~lip_ros.hsc4d.sensors.REFINED_TOPICS`), and
:func:`write_refinement_bag` records them (reliable; the map latched, as a
map is published).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import QosDurability, QosReliability

from lip_msgs_py import (
    Backend,
    MalformedMessageError,
    RosbagsBackend,
    cloud_to_xyz_time,
    msg_to_imu,
    msg_to_odometry,
    odometry_to_msg,
    read_header,
    xyz_to_cloud,
)
from lip_ros.bagio import RELIABLE_QOS, bag_qos, mcap_writer, read_messages
from lip_ros.core.rotations import matrix_to_quat
from lip_ros.core.skeleton import Skeleton
from lip_ros.hsc4d.refinement import CaptureRefiner, Refinement, RefinementConfig
from lip_ros.hsc4d.sensors import (
    HIP_LIDAR_TOPIC,
    MAP_FRAME,
    PELVIS_FRAME,
    REFINED_MAP_TOPIC,
    REFINED_ODOMETRY_TOPIC,
    REFINED_TOPICS,
    SUIT_ODOMETRY_TOPIC,
    suit_imu_topic,
)
from lip_ros.hsc4d.suit_restart import SuitRestart
from lip_ros.outputs import pose_messages

__all__ = ["refine_bag", "refinement_messages", "write_refinement_bag", "LATER_CAPTURE"]

#: how :func:`refine_bag` counts the sweeps of a capture after the first in the bag
LATER_CAPTURE = "sweep: of a later capture (only the first is refined)"

_LATCHED_QOS = bag_qos(QosReliability.RELIABLE, 1, QosDurability.TRANSIENT_LOCAL)


def refine_bag(bag: str | Path, config: RefinementConfig | None = None,
               progress: Callable[[int], None] | None = None) -> tuple[CaptureRefiner, Refinement, Counter[str]]:
    """Refine the HSC4D capture in ``bag`` (``progress(sweeps)`` after each sweep): the refiner (its live record
    and pipeline), the refinement, and the messages left out by reason. ValueError if nothing could be posed."""
    refiner = CaptureRefiner(config)
    restart = SuitRestart()
    later = False  # a new capture began: the rest is not the refined one's
    segment_of = {suit_imu_topic(s): s for s in refiner.body.segments}
    skipped: Counter[str] = Counter()
    held: dict[str, list[Any]] = {s: [] for s in refiner.body.segments}  # suit samples since the last sweep
    last_ns: int | None = None
    sweeps = 0
    for m in read_messages(bag, [HIP_LIDAR_TOPIC, SUIT_ODOMETRY_TOPIC, *segment_of]):
        if later:
            if m.topic == HIP_LIDAR_TOPIC:
                skipped[LATER_CAPTURE] += 1
            continue
        try:
            if m.topic in segment_of:
                held[segment_of[m.topic]].append(msg_to_imu(m.msg))
            elif m.topic == SUIT_ODOMETRY_TOPIC:
                o = msg_to_odometry(m.msg)
                later = restart.add(o.stamp_ns, o.position, o.quat) is not None
                if later:
                    continue
                if reason := refiner.add_suit_odometry(o.stamp_ns, o.position, o.quat):
                    skipped[f"suit odometry: {reason}"] += 1
            else:
                for segment, samples in held.items():  # many samples of a segment at once cost what one does
                    skipped.update(f"suit {segment}: {r}" for r in refiner.add_suit_imu(segment, samples) if r)
                    samples.clear()
                stamp_ns = read_header(m.msg)[0]
                points, t = cloud_to_xyz_time(m.msg)
                if not len(points):
                    skipped["sweep: no finite point"] += 1
                elif last_ns is not None and stamp_ns <= last_ns:
                    skipped["sweep: not after the last"] += 1
                else:
                    refiner.add_sweep(points.astype(np.float64), stamp_ns + t.astype(np.int64), stamp_ns)
                    last_ns = stamp_ns
                sweeps += 1
                if progress is not None:
                    progress(sweeps)
        except MalformedMessageError as exc:
            skipped[f"{m.topic}: malformed: {str(exc).split(':')[0][:60]}"] += 1
    return refiner, refiner.refine(), skipped


def refinement_messages(backend: Backend, refinement: Refinement, skeleton: Skeleton
                        ) -> Iterator[tuple[int, str, str, Any]]:
    """(stamp ns, topic, message type, message) of the refined outputs: per sweep the odometry and the body's
    pose topics, stamped with its reference time; then the map (S_opt), stamped with the last."""
    r = refinement
    for k, stamp in enumerate(r.stamps_ns.tolist()):
        T = r.pelvis[k]
        yield stamp, REFINED_ODOMETRY_TOPIC, "nav_msgs/msg/Odometry", odometry_to_msg(
            backend, stamp, MAP_FRAME, PELVIS_FRAME, T[:3, 3], matrix_to_quat(T[:3, :3]))
        for topic, (msgtype, msg) in pose_messages(backend, REFINED_TOPICS, skeleton, stamp, MAP_FRAME,
                                                   r.body.local_rot[k], r.body.glob_rot[k], r.body.joints[k]).items():
            yield stamp, topic, msgtype, msg
    if len(r.stamps_ns):
        last = int(r.stamps_ns[-1])
        yield last, REFINED_MAP_TOPIC, "sensor_msgs/msg/PointCloud2", xyz_to_cloud(backend, r.map, last, MAP_FRAME)


def write_refinement_bag(refinement: Refinement, skeleton: Skeleton, out: Path) -> dict[str, int]:
    """Record :func:`refinement_messages` to the new bag directory ``out``, each logged at its stamp; the message
    count per topic."""
    backend = RosbagsBackend()
    counts: dict[str, int] = {}
    conns: dict[str, Any] = {}
    with mcap_writer(out, zstd=True) as writer:
        for stamp, topic, msgtype, msg in refinement_messages(backend, refinement, skeleton):
            if topic not in conns:
                qos = _LATCHED_QOS if topic == REFINED_MAP_TOPIC else RELIABLE_QOS
                conns[topic] = writer.add_connection(topic, msgtype, typestore=backend.typestore,
                                                     offered_qos_profiles=[qos])
            writer.write(conns[topic], stamp, backend.serialize(msg, msgtype))
            counts[topic] = counts.get(topic, 0) + 1
    return counts
