"""sensor_msgs/PointCloud2 <-> structured numpy arrays, and a fast path to valid xyz points.

Readers are zero-copy where the layout allows: the structured array returned by
``cloud_to_array`` is a read-only view of ``msg.data`` (copy it to keep or edit
it). Organized clouds (height > 1) keep their ``(height, width)`` shape,
unorganized ones (height 1) are ``(width,)``. Fields are looked up by name and
offset, ``is_bigendian`` gives the byte order, ``PointField.count > 1`` becomes
a numpy subarray field. Layout violations raise ``MalformedMessageError``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from lip_msgs_py.backend import Backend
from lip_msgs_py.errors import MalformedMessageError

__all__ = [
    "POINT_FIELD_DATATYPES",
    "XYZ_DTYPE",
    "cloud_dtype",
    "cloud_to_array",
    "cloud_to_xyz",
    "cloud_to_xyz_time",
    "array_to_cloud",
    "xyz_to_cloud",
]

#: sensor_msgs/PointField datatype constants -> numpy type codes (byte order added per cloud).
POINT_FIELD_DATATYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_DATATYPE_OF_CODE = {code: datatype for datatype, code in POINT_FIELD_DATATYPES.items()}

#: Plain x, y, z float32 points (point_step 12).
XYZ_DTYPE = np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3, "offsets": [0, 4, 8], "itemsize": 12})

def cloud_dtype(msg: Any, fields: Sequence[str] | None = None) -> np.dtype:
    """Structured dtype of one point of ``msg`` (itemsize ``point_step``), optionally only ``fields``."""
    point_step = int(msg.point_step)
    if point_step <= 0:
        raise MalformedMessageError(f"PointCloud2: point_step {point_step} must be positive")
    order = ">" if msg.is_bigendian else "<"
    entries: dict[str, tuple[np.dtype, int]] = {}
    for f in msg.fields:
        name, offset, datatype, count = str(f.name), int(f.offset), int(f.datatype), int(f.count)
        if not name or name in entries:
            raise MalformedMessageError(f"PointCloud2: empty or duplicate field name {name!r}")
        if datatype not in POINT_FIELD_DATATYPES:
            raise MalformedMessageError(f"PointCloud2: field {name!r} has unknown datatype {datatype}")
        if count < 1:
            raise MalformedMessageError(f"PointCloud2: field {name!r} has count {count} (must be >= 1)")
        base = np.dtype(order + POINT_FIELD_DATATYPES[datatype])
        fmt = base if count == 1 else np.dtype((base, (count,)))
        if offset < 0 or offset + fmt.itemsize > point_step:
            raise MalformedMessageError(
                f"PointCloud2: field {name!r} (offset {offset}, {fmt.itemsize} bytes) lies beyond "
                f"point_step {point_step}"
            )
        entries[name] = (fmt, offset)
    by_offset = sorted(entries.items(), key=lambda kv: kv[1][1])
    for (name_a, (fmt_a, off_a)), (name_b, (_, off_b)) in zip(by_offset, by_offset[1:]):
        if off_a + fmt_a.itemsize > off_b:
            raise MalformedMessageError(f"PointCloud2: fields {name_a!r} and {name_b!r} overlap")
    if fields is not None:
        missing = [name for name in fields if name not in entries]
        if missing:
            raise MalformedMessageError(f"PointCloud2: missing field(s) {missing}; the cloud has {list(entries)}")
        entries = {name: entries[name] for name in fields}
    return np.dtype(
        {
            "names": list(entries),
            "formats": [fmt for fmt, _ in entries.values()],
            "offsets": [off for _, off in entries.values()],
            "itemsize": point_step,
        }
    )


def _checked_bytes(msg: Any) -> tuple[np.ndarray, int, int, int, int]:
    """``(data as uint8, height, width, point_step, row_step)`` after the size checks."""
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    if height < 0 or width < 0:
        raise MalformedMessageError(f"PointCloud2: negative size {height} x {width}")
    if row_step < point_step * width:
        raise MalformedMessageError(f"PointCloud2: row_step {row_step} < point_step {point_step} * width {width}")
    try:
        view = memoryview(msg.data)
    except TypeError:
        kind = type(msg.data).__name__
        raise MalformedMessageError(f"PointCloud2: data of type {kind} is not a byte buffer") from None
    if view.itemsize != 1 or not view.c_contiguous:
        raise MalformedMessageError("PointCloud2: data is not a contiguous buffer of bytes")
    if view.nbytes != row_step * height:
        raise MalformedMessageError(f"PointCloud2: len(data) {view.nbytes} != row_step {row_step} * height {height}")
    if height * width == 0:  # numpy wants a buffer for one point even for zero points
        return np.zeros(point_step, dtype=np.uint8), height, width, point_step, row_step
    return np.frombuffer(view, dtype=np.uint8), height, width, point_step, row_step


def cloud_to_array(msg: Any, fields: Sequence[str] | None = None) -> np.ndarray:
    """Read-only structured view of the points: shape (height, width) if organized, else (width,)."""
    dtype = cloud_dtype(msg, fields)
    data, height, width, point_step, row_step = _checked_bytes(msg)
    if height > 1:
        points = np.ndarray((height, width), dtype, data, 0, (row_step, point_step))
    else:
        points = np.ndarray((height * width,), dtype, data, 0, (point_step,))
    points.flags.writeable = False
    return points


def _packed_points(msg: Any) -> tuple[np.ndarray, int, int]:
    """``(bytes, n, point_step)`` with point i at byte i * point_step (copies only if rows are padded)."""
    data, height, width, point_step, row_step = _checked_bytes(msg)
    if height > 1 and width > 0 and row_step != point_step * width:
        data = data.reshape(height, row_step)[:, : point_step * width].reshape(-1)
    return data, height * width, point_step


def _column(data: np.ndarray, n: int, step: int, dtype: np.dtype, name: str) -> np.ndarray:
    fmt, offset = dtype.fields[name][:2]
    return np.ndarray((n,), fmt, data, offset, (step,))


def _valid_xyz(msg: Any, extra: tuple[str, ...]) -> tuple[np.ndarray, list[np.ndarray]]:
    """(N, 3) float32 finite points and, for each of ``extra``, those points' values (native order)."""
    names = ("x", "y", "z") + extra
    dtype = cloud_dtype(msg, names)
    for name in names:
        if dtype.fields[name][0].shape:
            raise MalformedMessageError(f"PointCloud2: field {name!r} has count > 1; it must be a scalar")
    data, n, step = _packed_points(msg)
    x, y, z = (_column(data, n, step, dtype, c) for c in "xyz")
    fmt, off, size = x.dtype, dtype.fields["x"][1], x.dtype.itemsize
    packed = None
    offsets = (dtype.fields["y"][1], dtype.fields["z"][1])
    if y.dtype == fmt == z.dtype and offsets == (off + size, off + 2 * size):
        # x, y, z adjacent and alike: gather every point's triple in one pass, then filter in cache.
        packed = np.ndarray((n,), np.dtype((np.void, 3 * size)), data, off, (step,)).copy()
        x, y, z = packed.view(fmt).reshape(-1, 3).T
    valid = np.isfinite(x)
    valid &= np.isfinite(y)
    valid &= np.isfinite(z)
    if packed is not None:
        xyz = np.compress(valid, packed).view(fmt).reshape(-1, 3)
    else:
        xyz = np.stack([np.compress(valid, c) for c in (x, y, z)], axis=1)
    values = [np.compress(valid, _column(data, n, step, dtype, name)) for name in extra]
    native = [v.astype(v.dtype.newbyteorder("="), copy=False) for v in values]
    return xyz.astype(np.float32, copy=False), native


def cloud_to_xyz(msg: Any) -> np.ndarray:
    """(N, 3) float32 array of the points whose x, y and z are all finite, in data order."""
    return _valid_xyz(msg, ())[0]


def cloud_to_xyz_time(msg: Any, time_field: str = "t") -> tuple[np.ndarray, np.ndarray]:
    """``cloud_to_xyz`` plus those points' ``time_field`` values (native byte order, the field's type).

    For Ouster ``original`` clouds ``t`` is uint32 ns after ``header.stamp``.
    """
    xyz, (t,) = _valid_xyz(msg, (time_field,))
    return xyz, t


def _point_fields(dtype: np.dtype) -> tuple[list[tuple[str, int, int, int]], bool]:
    """``([(name, offset, datatype, count)], is_bigendian)`` of a structured point dtype."""
    if dtype.names is None:
        raise MalformedMessageError(f"points must be a structured array, got dtype {dtype}")
    fields, orders = [], set()
    for name in dtype.names:
        fmt, offset = dtype.fields[name][:2]
        base, shape = (fmt.subdtype if fmt.subdtype is not None else (fmt, ()))
        code = f"{base.kind}{base.itemsize}"
        if code not in _DATATYPE_OF_CODE:
            raise MalformedMessageError(f"field {name!r} has dtype {fmt}, which PointField cannot represent")
        if base.itemsize > 1:
            orders.add({"=": "<" if sys.byteorder == "little" else ">"}.get(base.byteorder, base.byteorder))
        fields.append((name, offset, _DATATYPE_OF_CODE[code], int(np.prod(shape, dtype=np.int64))))
    if len(orders) > 1:
        raise MalformedMessageError("points mix little- and big-endian fields")
    return fields, orders == {">"}


def array_to_cloud(
    backend: Backend, points: np.ndarray, stamp_ns: int, frame_id: str, is_dense: bool | None = None
) -> Any:
    """PointCloud2 of a structured array, (H, W) organized or (N,) unorganized, padding kept.

    ``is_dense`` None: True unless the cloud has x, y, z and some point is not finite there.
    """
    points = np.asarray(points)
    fields, big_endian = _point_fields(points.dtype)
    if points.ndim not in (1, 2):
        raise MalformedMessageError(f"points must be 1-D or 2-D, got shape {points.shape}")
    height, width = points.shape if points.ndim == 2 else (1, points.shape[0])
    if is_dense is None:
        names = points.dtype.names
        is_dense = not all(c in names for c in "xyz") or all(bool(np.isfinite(points[c]).all()) for c in "xyz")
    point_step = points.dtype.itemsize
    return backend.msg(
        "sensor_msgs/msg/PointCloud2",
        header=backend.header(stamp_ns, frame_id),
        height=height,
        width=width,
        fields=[
            backend.msg("sensor_msgs/msg/PointField", name=name, offset=offset, datatype=datatype, count=count)
            for name, offset, datatype, count in fields
        ],
        is_bigendian=big_endian,
        point_step=point_step,
        row_step=point_step * width,
        data=np.ascontiguousarray(points).view(np.uint8).reshape(-1),
        is_dense=bool(is_dense),
    )


def xyz_to_cloud(backend: Backend, xyz: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
    """PointCloud2 of ``XYZ_DTYPE`` points from an (N, 3) or organized (H, W, 3) array."""
    xyz = np.ascontiguousarray(xyz, dtype="<f4")
    if xyz.ndim not in (2, 3) or xyz.shape[-1] != 3:
        raise MalformedMessageError(f"xyz must be (N, 3) or (H, W, 3), got shape {xyz.shape}")
    return array_to_cloud(backend, xyz.view(XYZ_DTYPE)[..., 0], stamp_ns, frame_id)
