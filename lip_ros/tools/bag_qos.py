"""QoS of recorded topics: rosbag2's offered-QoS records to and from rclpy, and one profile for several offers."""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from lip_msgs_py.stamps import NS_PER_S
from lip_ros.bagio import INFINITE

__all__ = ["qos_to_rclpy", "qos_to_bag", "common_qos"]

_INFINITE_NS = INFINITE.sec * NS_PER_S + INFINITE.nsec
DEFAULT_DEPTH = 10  # rclpy's default profile, which ros2 bag play also uses for topics recorded without QoS


def _duration(t: QosTime) -> Duration:
    """rclpy duration of a recorded one; infinite (no deadline, no lifespan) as rmw's default."""
    ns = t.sec * NS_PER_S + t.nsec
    return Duration() if ns >= _INFINITE_NS else Duration(nanoseconds=ns)


def _qos_time(d: Duration) -> QosTime:
    """Recorded duration of an rclpy one; rmw's default and infinite both as rosbag2 writes infinity."""
    ns = d.nanoseconds
    return INFINITE if ns <= 0 or ns >= _INFINITE_NS else QosTime(*divmod(ns, NS_PER_S))


def _liveliness(name: str) -> LivelinessPolicy:
    return LivelinessPolicy.__members__.get(name, LivelinessPolicy.SYSTEM_DEFAULT)  # MANUAL_BY_NODE is gone


def qos_to_rclpy(q: Qos) -> QoSProfile:
    """The rclpy profile of a QoS record from a bag's metadata."""
    return QoSProfile(history=HistoryPolicy[q.history.name], depth=q.depth,
                      reliability=ReliabilityPolicy[q.reliability.name], durability=DurabilityPolicy[q.durability.name],
                      deadline=_duration(q.deadline), lifespan=_duration(q.lifespan),
                      liveliness=_liveliness(q.liveliness.name),
                      liveliness_lease_duration=_duration(q.liveliness_lease_duration),
                      avoid_ros_namespace_conventions=q.avoid_ros_namespace_conventions)


def qos_to_bag(p: QoSProfile) -> Qos:
    """The QoS record rosbag2 writes for a publisher that offered ``p``."""
    return Qos(QosHistory[p.history.name], p.depth, QosReliability[p.reliability.name],
               QosDurability[p.durability.name], _qos_time(p.deadline), _qos_time(p.lifespan),
               QosLiveliness[p.liveliness.name], _qos_time(p.liveliness_lease_duration),
               p.avoid_ros_namespace_conventions)


def common_qos(offers: Sequence[QoSProfile], depth: int | None = None) -> QoSProfile:
    """One profile compatible with every offer: reliable, transient local only where all offers are.

    Keep last ``depth`` (default: the deepest keep-last offer, or 10). With no offers: reliable, volatile.
    """
    if depth is None:
        depth = max((o.depth for o in offers if o.history == HistoryPolicy.KEEP_LAST), default=DEFAULT_DEPTH)
    reliable = all(o.reliability == ReliabilityPolicy.RELIABLE for o in offers)
    transient = bool(offers) and all(o.durability == DurabilityPolicy.TRANSIENT_LOCAL for o in offers)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(depth, 1),
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)
