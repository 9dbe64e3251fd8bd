"""The pose outputs' messages (and Imu) written straight to little-endian CDR bytes, without message objects.

A live node publishes these bytes as they are (rclpy's ``Publisher.publish``
takes serialized messages): building the same messages as rclpy objects, field
by field, cost a node about 2 ms a frame (a PoseArray of 24 poses, a
MarkerArray of 70 points), the serialisation a few hundredths of that. The
arrays are validated as by the object writers (:mod:`lip_msgs_py.pose`,
:mod:`lip_msgs_py.markers`: shapes, finite values, unit quaternions), and the
bytes decode to the messages those writers build (tested against rclpy's and
rosbags' deserialisers). Padding bytes are zeros and nothing trails the last
field, as rosbags writes CDR.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import lru_cache
from typing import Any

import numpy as np

from lip_msgs_py._validate import finite_array, unit_quaternions
from lip_msgs_py.imu import ImuSample, imu_values
from lip_msgs_py.markers import (
    ADD,
    IDENTITY_POSE,
    JOINT_DIAMETER_M,
    LINE_WIDTH_M,
    SKELETON_COLOR,
    SKELETON_NS,
    skeleton_marker_specs,
)
from lip_msgs_py.pose import unique_names
from lip_msgs_py.stamps import ns_to_sec_nanosec

__all__ = ["pose_stamped_cdr", "pose_array_cdr", "joint_state_cdr", "skeleton_markers_cdr", "imu_cdr"]

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE, no options
_U32 = struct.Struct("<I")
_I32x3 = struct.Struct("<iii")
_STAMP = struct.Struct("<iI")


class _Cdr:
    """A CDR message being written; every field aligned to its size, counted from the end of the encapsulation
    header."""

    def __init__(self) -> None:
        self.buf = bytearray(_ENCAPSULATION)

    def align(self, size: int) -> None:
        self.buf += bytes(-(len(self.buf) - len(_ENCAPSULATION)) % size)

    def pack(self, fmt: struct.Struct, *values: Any) -> None:
        """Primitives of one size (4 bytes: ``fmt`` of ints, or of floats)."""
        self.align(4)
        self.buf += fmt.pack(*values)

    def u32(self, value: int) -> None:
        self.pack(_U32, value)

    def byte(self, value: int) -> None:
        self.buf.append(value)

    def string(self, text: str) -> None:
        raw = text.encode()
        self.u32(len(raw) + 1)
        self.buf += raw + b"\x00"

    def float64s(self, values: np.ndarray) -> None:
        """float64 values in C order (8-aligned), e.g. a Pose, or a sequence of Points or Poses after its count."""
        self.align(8)
        self.buf += np.ascontiguousarray(values, dtype="<f8").tobytes()

    def header(self, stamp_ns: int, frame_id: str) -> None:
        self.pack(_STAMP, *ns_to_sec_nanosec(stamp_ns))
        self.string(frame_id)

    def strings(self, texts: tuple[str, ...]) -> None:
        """A sequence of strings: its bytes depend only on them (strings align to 4, as the count before them)."""
        self.align(4)
        self.buf += _string_sequence(texts)

    def bytes(self) -> bytes:
        return bytes(self.buf)


@lru_cache(maxsize=8)
def _string_sequence(texts: tuple[str, ...]) -> bytes:
    """A sequence<string>'s bytes from a 4-aligned offset (the same joint names every frame)."""
    cdr = _Cdr()
    cdr.u32(len(texts))
    for text in texts:
        cdr.string(text)
    return cdr.bytes()[len(_ENCAPSULATION):]


def pose_stamped_cdr(stamp_ns: int, frame_id: str, position: Any, quat: Any) -> bytes:
    """``geometry_msgs/msg/PoseStamped`` of a position (3,) and an xyzw quaternion (4,), as CDR."""
    p = finite_array(position, (3,), "PoseStamped position")
    q = unit_quaternions(quat, (), "PoseStamped orientation")
    cdr = _Cdr()
    cdr.header(stamp_ns, frame_id)
    cdr.float64s(np.concatenate([p, q]))
    return cdr.bytes()


def pose_array_cdr(stamp_ns: int, frame_id: str, positions: Any, quats: Any) -> bytes:
    """``geometry_msgs/msg/PoseArray`` of positions (N, 3) and xyzw quaternions (N, 4), as CDR."""
    p = finite_array(positions, (None, 3), "PoseArray positions")
    q = unit_quaternions(quats, (len(p),), "PoseArray orientations")
    cdr = _Cdr()
    cdr.header(stamp_ns, frame_id)
    cdr.u32(len(p))
    cdr.float64s(np.concatenate([p, q], axis=1))
    return cdr.bytes()


def joint_state_cdr(stamp_ns: int, frame_id: str, names: Sequence[str], positions: Any) -> bytes:
    """``sensor_msgs/msg/JointState`` with ``positions`` (J,) for ``names`` (velocity and effort empty), as CDR."""
    names = unique_names(names, "JointState")
    positions = finite_array(positions, (len(names),), "JointState position")
    cdr = _Cdr()
    cdr.header(stamp_ns, frame_id)
    cdr.strings(names)
    cdr.u32(len(positions))
    cdr.float64s(positions)
    cdr.u32(0)  # velocity
    cdr.u32(0)  # effort
    return cdr.bytes()


def skeleton_markers_cdr(
    stamp_ns: int,
    frame_id: str,
    positions: Any,
    parents: Any,
    ns: str = SKELETON_NS,
    color: Sequence[float] = SKELETON_COLOR,
    joint_color: Sequence[float] | None = None,
    line_width: float = LINE_WIDTH_M,
    joint_diameter: float = JOINT_DIAMETER_M,
    lifetime_ns: int = 0,
) -> bytes:
    """The ``visualization_msgs/msg/MarkerArray`` of :func:`lip_msgs_py.skeleton_to_markers` (the same
    arguments), as CDR."""
    specs = skeleton_marker_specs(positions, parents, color, joint_color, line_width, joint_diameter)
    cdr = _Cdr()
    cdr.u32(len(specs))
    for m in specs:
        cdr.header(stamp_ns, frame_id)
        cdr.string(str(ns))
        cdr.pack(_I32x3, m.marker_id, m.kind, ADD)
        cdr.float64s(np.concatenate([*IDENTITY_POSE, np.full(3, m.scale)]))  # pose, scale
        cdr.buf += m.rgba.astype("<f4").tobytes()  # 4-aligned after the float64s
        cdr.pack(_STAMP, *ns_to_sec_nanosec(lifetime_ns))
        cdr.byte(0)  # frame_locked
        cdr.u32(len(m.points))
        cdr.float64s(m.points)
        cdr.u32(0)  # colors
        cdr.string("")  # texture_resource
        cdr.header(0, "")  # texture (sensor_msgs/CompressedImage): header, format, data
        cdr.string("")
        cdr.u32(0)
        cdr.u32(0)  # uv_coordinates
        cdr.string("")  # text
        cdr.string("")  # mesh_resource
        cdr.string("")  # mesh_file (visualization_msgs/MeshFile): filename, data
        cdr.u32(0)
        cdr.byte(0)  # mesh_use_embedded_materials
    return cdr.bytes()


def imu_cdr(sample: ImuSample) -> bytes:
    """``sensor_msgs/msg/Imu`` of a sample, as :func:`lip_msgs_py.imu_to_msg` builds it, as CDR."""
    cdr = _Cdr()
    cdr.header(sample.stamp_ns, sample.frame_id)
    cdr.float64s(imu_values(sample))
    return cdr.bytes()
