"""sensor_msgs PointCloud2 and Imu straight from little-endian CDR bytes, without message objects.

For batch processing of bags (:func:`lip_ros.lip.batch.process_bag_batch`), and
for live nodes with many fast inputs (raw subscriptions), where building
message objects costs more than the work on them:

* :func:`cloud_msg` parses a PointCloud2's header and layout into a
  duck-typed message whose point data is a zero-copy view of the bytes, for
  the ``lip_msgs_py`` readers (``cloud_to_array``, ``read_header``): their
  checks and errors apply unchanged.
* :func:`imu_samples` decodes many Imu messages at once and validates them
  together, giving what :func:`lip_msgs_py.msg_to_imu` gives for each, bit for
  bit; :func:`cdr_stamp` reads a message's header stamp alone.

Both return None for what they leave to the rosbags deserialiser and
``lip_msgs_py`` (big-endian CDR, unexpected sizes, and for Imu any message that
``msg_to_imu`` would refuse: a provided value not finite, a stamp or a
quaternion norm out of range), so that every message, well-formed or not, ends
up as it would through rosbags. An Imu component not provided (REP-145:
covariance[0] = -1, e.g. the gyro of the LIP graph's bones) is NaN, as
``msg_to_imu`` gives it.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lip_msgs_py import ImuSample
from lip_msgs_py._validate import QUAT_UNIT_TOLERANCE
from lip_msgs_py.errors import MalformedMessageError
from lip_msgs_py.stamps import NS_PER_S

__all__ = ["CloudMsg", "cloud_msg", "imu_samples", "cdr_stamp", "with_cdr_stamp"]

_LITTLE_ENDIAN = b"\x00\x01"  # CDR_LE encapsulation
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_SIZE = struct.Struct("<II")  # height, width
_FIELD = struct.Struct("<IBxxxI")  # PointField offset, datatype, (padding), count
_STEPS = struct.Struct("<III")  # point_step, row_step, data length
_IMU_HEAD = struct.Struct("<iII")  # stamp sec and nanosec, frame_id length
_IMU_VALUES = 37  # orientation (4) + covariance (9), angular velocity (3) + (9), linear acceleration (3) + (9)
_IMU_BYTES = 8 * _IMU_VALUES
_NAN_VALUES = np.full(_IMU_VALUES, np.nan).tobytes()  # stands in for a message that is not plain
_NOT_PROVIDED = -1.0  # REP-145 covariance[0]
#: The Imu's components among the 37 values: (the values, their covariance) of the orientation, the angular
#: velocity and the linear acceleration.
_IMU_PARTS = ((slice(0, 4), slice(4, 13)), (slice(13, 16), slice(16, 25)), (slice(25, 28), slice(28, 37)))


@dataclass(frozen=True)
class _Stamp:
    sec: int
    nanosec: int


@dataclass(frozen=True)
class _Header:
    stamp: _Stamp
    frame_id: str


@dataclass(frozen=True)
class _PointField:
    name: str
    offset: int
    datatype: int
    count: int


@dataclass(frozen=True)
class CloudMsg:
    """The fields of a sensor_msgs/PointCloud2 as the ``lip_msgs_py`` readers use them; ``data`` views the CDR."""

    header: _Header
    height: int
    width: int
    fields: tuple[_PointField, ...]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: memoryview
    is_dense: bool


class _Cursor:
    """Reads CDR primitives in order, aligned relative to the payload after the 4-byte encapsulation header."""

    def __init__(self, data: memoryview) -> None:
        self.data = data
        self.pos = 4

    def unpack(self, fmt: struct.Struct) -> tuple[Any, ...]:
        """``fmt`` (4-byte types) at the next 4-byte boundary."""
        self.pos += -(self.pos - 4) % 4
        values = fmt.unpack_from(self.data, self.pos)
        self.pos += fmt.size
        return values

    def byte(self) -> int:
        self.pos += 1
        return self.data[self.pos - 1]

    def string(self) -> str:
        (length,) = self.unpack(_U32)
        start, self.pos = self.pos, self.pos + length
        if self.pos > len(self.data):
            raise ValueError("string beyond the data")
        return bytes(self.data[start : self.pos - 1]).decode()

    def header(self) -> _Header:
        sec, nanosec = self.unpack(_STAMP)
        return _Header(_Stamp(sec, nanosec), self.string())

    def done(self) -> bool:
        """Whether the data ends here (up to the alignment padding rosbags also accepts)."""
        return 0 <= len(self.data) - self.pos <= 3


def cloud_msg(data: bytes | memoryview) -> CloudMsg | None:
    """The PointCloud2 of little-endian CDR ``data`` (its point data a view of it); None if not such plain CDR."""
    data = memoryview(data)
    if bytes(data[:2]) != _LITTLE_ENDIAN:
        return None
    c = _Cursor(data)
    try:
        header = c.header()
        height, width = c.unpack(_SIZE)
        fields = tuple(_PointField(c.string(), *c.unpack(_FIELD)) for _ in range(c.unpack(_U32)[0]))
        is_bigendian = bool(c.byte())
        point_step, row_step, size = c.unpack(_STEPS)
        points = data[c.pos : c.pos + size]
        c.pos += size
        is_dense = bool(c.byte())
    except (struct.error, ValueError, IndexError):  # UnicodeDecodeError is a ValueError
        return None
    if len(points) != size or not c.done():
        return None
    return CloudMsg(header, height, width, fields, is_bigendian, point_step, row_step, points, is_dense)


def imu_samples(datas: Sequence[bytes | memoryview]) -> list[ImuSample | None]:
    """The ImuSamples of sensor_msgs/Imu messages (little-endian CDR), as ``msg_to_imu`` gives them; None for
    a message that needs ``msg_to_imu`` itself (see the module)."""
    views = [memoryview(d) for d in datas]
    heads = [_imu_head(v) for v in views]
    values = np.frombuffer(bytearray().join(v[h[2] : h[2] + _IMU_BYTES] if h else _NAN_VALUES
                                            for v, h in zip(views, heads, strict=True)), "<f8").reshape(-1, _IMU_VALUES)
    # per component (orientation, angular velocity, linear acceleration): its values and its covariance
    parts = [(values[:, v], values[:, c]) for v, c in _IMU_PARTS]
    provided = np.stack([cov[:, 0] != _NOT_PROVIDED for _, cov in parts], axis=1)  # (N, 3)
    finite = np.stack([np.isfinite(v).all(axis=1) & np.isfinite(c).all(axis=1) for v, c in parts], axis=1)
    quat = parts[0][0]
    norm = np.linalg.norm(quat, axis=-1, keepdims=True)  # as lip_msgs_py's unit_quaternions, row by row
    unit_ok = np.abs(norm[:, 0] - 1.0) <= QUAT_UNIT_TOLERANCE
    plain = (finite | ~provided).all(axis=1) & (unit_ok | ~provided[:, 0])
    unit = quat / np.where((plain & provided[:, 0])[:, None], norm, 1.0)
    absent = np.full((3, 3), np.nan)
    out: list[ImuSample | None] = []
    for k, (head, ok) in enumerate(zip(heads, plain.tolist(), strict=True)):
        if not ok:
            out.append(None)
            continue
        comps = [(unit[k] if i == 0 else v[k], c[k].reshape(3, 3)) if provided[k, i]
                 else (np.full(len(v[k]), np.nan), absent.copy()) for i, (v, c) in enumerate(parts)]
        out.append(ImuSample(head[0], head[1], comps[0][0], comps[1][0], comps[2][0],
                             comps[0][1], comps[1][1], comps[2][1]))
    return out


def cdr_stamp(data: bytes | memoryview) -> int:
    """The header stamp (ns) of a little-endian CDR message that starts with a std_msgs/Header (a live node's
    quick look, e.g. at raw Imu bytes); MalformedMessageError if it cannot be read so."""
    if bytes(data[:2]) != _LITTLE_ENDIAN or len(data) < 12:
        raise MalformedMessageError("CDR: not a little-endian message with a header")
    sec, nanosec = _STAMP.unpack_from(data, 4)
    if not 0 <= nanosec < NS_PER_S:
        raise MalformedMessageError(f"CDR: header stamp nanosec {nanosec} out of range")
    return sec * NS_PER_S + nanosec


def with_cdr_stamp(data: bytes | memoryview, stamp_ns: int) -> bytes:
    """A copy of a little-endian CDR message that starts with a std_msgs/Header, stamped ``stamp_ns`` (the rest of
    the bytes as they were); MalformedMessageError as :func:`cdr_stamp`."""
    cdr_stamp(data)
    out = bytearray(data)
    _STAMP.pack_into(out, 4, *divmod(int(stamp_ns), NS_PER_S))
    return bytes(out)


def _imu_head(data: memoryview) -> tuple[int, str, int] | None:
    """Stamp (ns), frame id and the offset of the 37 values of one Imu message; None if it is not plain."""
    try:
        if bytes(data[:2]) != _LITTLE_ENDIAN:
            return None
        sec, nanosec, length = _IMU_HEAD.unpack_from(data, 4)
        frame_id = bytes(data[16 : 15 + length]).decode() if length else ""
    except (struct.error, ValueError):  # UnicodeDecodeError is a ValueError
        return None
    start = 4 + 12 + length
    start += -(start - 4) % 8
    if not 0 <= nanosec < NS_PER_S or not 0 <= len(data) - (start + _IMU_BYTES) <= 3:
        return None
    return sec * NS_PER_S + nanosec, frame_id, start
