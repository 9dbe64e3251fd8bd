"""PointCloud2 <-> numpy: layouts, organized shape, endianness, fast path, malformed clouds."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from lip_msgs_py import (
    OUSTER_ORIGINAL_DTYPE,
    XYZ_DTYPE,
    MalformedMessageError,
    RclpyBackend,
    RosbagsBackend,
    array_to_cloud,
    cloud_dtype,
    cloud_to_array,
    cloud_to_xyz,
    cloud_to_xyz_time,
    stamp_to_ns,
    xyz_to_cloud,
)
from lip_msgs_py.point_cloud2 import POINT_FIELD_DATATYPES

CLOUD = "sensor_msgs/msg/PointCloud2"
BACKENDS = [RclpyBackend(check_fields=True), RosbagsBackend()]


@pytest.fixture(params=BACKENDS, ids=["rclpy", "rosbags"])
def backend(request):
    return request.param


def ouster_scan(height: int = 16, width: int = 32, seed: int = 0) -> np.ndarray:
    """An Ouster ``original`` scan with about half the points no-return (NaN, range 0)."""
    rng = np.random.default_rng(seed)
    scan = np.zeros((height, width), OUSTER_ORIGINAL_DTYPE)
    for c in "xyz":
        scan[c] = rng.uniform(-20, 20, scan.shape)
    scan["intensity"] = rng.uniform(0, 1000, scan.shape)
    scan["t"] = (np.arange(width) * (100_000_000 // width))[None, :]
    scan["reflectivity"] = rng.integers(0, 255, scan.shape)
    scan["ring"] = np.arange(height)[:, None]
    scan["ambient"] = rng.integers(0, 4000, scan.shape)
    scan["range"] = rng.integers(500, 60000, scan.shape)
    miss = rng.random(scan.shape) < 0.5
    for c in "xyz":
        scan[c][miss] = np.nan
    scan["range"][miss] = 0
    return scan


def finite_xyz(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference for the fast path: (N, 3) float32 finite points and their indices, by plain numpy."""
    flat = points.reshape(-1)
    xyz = np.stack([flat[c].astype(np.float64) for c in "xyz"], axis=1)
    keep = np.isfinite(xyz).all(axis=1)
    return xyz[keep].astype(np.float32), np.flatnonzero(keep)


def remake(backend, msg, **changes):
    """A copy of a cloud message with some fields replaced."""
    names = ("height", "width", "fields", "is_bigendian", "point_step", "row_step", "is_dense")
    fields = {name: getattr(msg, name) for name in names}
    fields.update(changes)
    data = fields.pop("data", np.frombuffer(memoryview(msg.data), np.uint8))
    return backend.msg(CLOUD, header=msg.header, data=np.asarray(data, np.uint8), **fields)


def point_field(backend, name, offset, datatype=7, count=1):
    return backend.msg("sensor_msgs/msg/PointField", name=name, offset=offset, datatype=datatype, count=count)


def test_point_field_datatypes_match_both_message_definitions():
    from sensor_msgs.msg import PointField

    rosbags_cls = RosbagsBackend().typestore.types["sensor_msgs/msg/PointField"]
    names = ["INT8", "UINT8", "INT16", "UINT16", "INT32", "UINT32", "FLOAT32", "FLOAT64"]
    codes = ["i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"]
    for name, code in zip(names, codes):
        assert POINT_FIELD_DATATYPES[getattr(PointField, name)] == code
        assert POINT_FIELD_DATATYPES[getattr(rosbags_cls, name)] == code


def test_ouster_organized_round_trip_keeps_layout_shape_and_bytes(backend):
    scan = ouster_scan(16, 32)
    msg = array_to_cloud(backend, scan, 1_700_000_000_123_456_789, "os_lidar")
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (16, 32, 48, 48 * 32)
    assert not msg.is_bigendian and not msg.is_dense
    assert stamp_to_ns(msg.header.stamp) == 1_700_000_000_123_456_789 and msg.header.frame_id == "os_lidar"
    layout = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
    assert layout == [
        ("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 16, 7, 1), ("t", 20, 6, 1),
        ("reflectivity", 24, 4, 1), ("ring", 26, 4, 1), ("ambient", 28, 4, 1), ("range", 32, 6, 1),
    ]  # fmt: skip
    back = cloud_to_array(msg)
    assert back.shape == (16, 32)
    assert back.dtype == OUSTER_ORIGINAL_DTYPE
    assert back.tobytes() == scan.tobytes()  # every field, NaNs and the padding bytes
    assert np.array_equal(back["range"], scan["range"]) and np.isnan(back["x"]).sum() == np.isnan(scan["x"]).sum()


def test_round_trip_through_cdr_of_the_same_backend(backend):
    scan = ouster_scan(8, 16, seed=3)
    msg = backend.deserialize(backend.serialize(array_to_cloud(backend, scan, 5, "os_lidar"), CLOUD), CLOUD)
    assert cloud_to_array(msg).tobytes() == scan.tobytes()
    xyz, t = cloud_to_xyz_time(msg)
    ref, keep = finite_xyz(scan)
    assert np.array_equal(xyz, ref) and np.array_equal(t, scan["t"].reshape(-1)[keep])


def test_reader_is_a_read_only_view_of_the_message_data(backend):
    msg = array_to_cloud(backend, ouster_scan(4, 8), 0, "os_lidar")
    points = cloud_to_array(msg)
    assert np.shares_memory(points, np.frombuffer(memoryview(msg.data), np.uint8))
    with pytest.raises(ValueError):
        points["x"][0, 0] = 1.0


def test_unorganized_cloud_is_one_dimensional(backend):
    scan = ouster_scan(1, 50).reshape(-1)
    msg = array_to_cloud(backend, scan, 0, "os_lidar")
    assert (msg.height, msg.width) == (1, 50)
    assert cloud_to_array(msg).shape == (50,)
    assert cloud_to_array(msg).tobytes() == scan.tobytes()


@pytest.mark.parametrize(
    "dtype",
    [
        XYZ_DTYPE,
        np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")]),
        np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("label", "i1"), ("id", "<i2"), ("w", "<i4"), ("b", "u1")]),
    ],
    ids=["xyz", "xyzi", "float64-mixed"],
)
def test_any_field_set_round_trips(backend, dtype):
    rng = np.random.default_rng(1)
    points = np.zeros(20, dtype)
    for name in dtype.names:
        points[name] = rng.integers(-100, 100, 20) if dtype[name].kind == "i" else rng.uniform(0, 100, 20)
    msg = array_to_cloud(backend, points, 0, "map")
    assert msg.is_dense and msg.point_step == dtype.itemsize
    back = cloud_to_array(msg)
    assert back.dtype == dtype.newbyteorder("<") and back.tobytes() == points.tobytes()
    assert np.array_equal(cloud_to_xyz(msg), np.stack([points[c] for c in "xyz"], 1).astype(np.float32))


def test_field_subset_keeps_offsets_and_point_step(backend):
    msg = array_to_cloud(backend, ouster_scan(4, 8), 0, "os_lidar")
    sub = cloud_to_array(msg, fields=["range", "x"])
    assert sub.dtype.names == ("range", "x") and sub.dtype.itemsize == 48
    assert sub.dtype.fields["range"][1] == 32
    assert np.array_equal(sub["range"], cloud_to_array(msg)["range"])


def test_count_greater_than_one_is_a_subarray(backend):
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("normal", "<f4", (3,)), ("rgb", "u1", (4,))])
    points = np.zeros(5, dtype)
    points["normal"] = np.arange(15, dtype=np.float32).reshape(5, 3)
    points["rgb"] = np.arange(20).reshape(5, 4)
    msg = array_to_cloud(backend, points, 0, "map")
    assert [(f.name, f.count) for f in msg.fields][3:] == [("normal", 3), ("rgb", 4)]
    back = cloud_to_array(msg)
    assert back["normal"].shape == (5, 3) and np.array_equal(back["normal"], points["normal"])
    assert np.array_equal(back["rgb"], points["rgb"])


def test_fast_path_returns_finite_points_in_order_with_time(backend):
    scan = ouster_scan(16, 64, seed=7)
    scan["z"][0, 1] = np.inf  # finite x, y but infinite z: not a valid point
    scan["x"][0, 2] = np.nan  # only x NaN
    msg = array_to_cloud(backend, scan, 0, "os_lidar")
    ref, keep = finite_xyz(scan)
    xyz = cloud_to_xyz(msg)
    assert xyz.dtype == np.float32 and xyz.shape == ref.shape and xyz.flags.c_contiguous
    assert np.array_equal(xyz, ref)
    assert 0 < len(xyz) < scan.size
    xyz_t, t = cloud_to_xyz_time(msg)
    assert np.array_equal(xyz_t, ref)
    assert t.dtype == np.uint32 and np.array_equal(t, scan["t"].reshape(-1)[keep])


def test_fast_path_with_non_adjacent_coordinates(backend):
    names, formats = ["z", "y", "x", "time"], ["<f8", "<f4", "<f4", "<f8"]
    dtype = np.dtype({"names": names, "formats": formats, "offsets": [0, 8, 16, 24], "itemsize": 40})
    points = np.zeros(6, dtype)
    points["x"], points["y"], points["z"] = np.arange(6), np.arange(6) + 10, np.arange(6) + 20
    points["time"] = np.linspace(0, 0.1, 6)
    points["y"][3] = np.nan
    msg = array_to_cloud(backend, points, 0, "map")
    xyz, t = cloud_to_xyz_time(msg, "time")
    keep = [0, 1, 2, 4, 5]
    assert np.array_equal(xyz, np.stack([points[c][keep] for c in "xyz"], 1).astype(np.float32))
    assert np.array_equal(t, points["time"][keep])


def big_endian_msg(backend, points: np.ndarray):
    """A cloud whose data is big-endian, as written by a big-endian host."""
    msg = array_to_cloud(backend, points, 0, "os_lidar")
    swapped = points.astype(points.dtype.newbyteorder(">"))
    return remake(backend, msg, is_bigendian=True, data=swapped.view(np.uint8).reshape(-1))


def test_big_endian_cloud_reads_correctly(backend):
    scan = ouster_scan(8, 16, seed=2)
    msg = big_endian_msg(backend, scan)
    assert np.frombuffer(memoryview(msg.data), np.uint8)[:4].tobytes() == scan["x"][0, :1].astype(">f4").tobytes()
    back = cloud_to_array(msg)
    assert back.dtype["x"].byteorder == ">"
    for name in OUSTER_ORIGINAL_DTYPE.names:
        assert np.array_equal(back[name], scan[name], equal_nan=True), name
    xyz, t = cloud_to_xyz_time(msg)
    ref, keep = finite_xyz(scan)
    assert np.array_equal(xyz, ref) and xyz.dtype == np.dtype("=f4")
    assert np.array_equal(t, scan["t"].reshape(-1)[keep]) and t.dtype.isnative


def test_big_endian_array_writes_a_big_endian_cloud(backend):
    scan = ouster_scan(4, 8)
    msg = array_to_cloud(backend, scan.astype(OUSTER_ORIGINAL_DTYPE.newbyteorder(">")), 0, "os_lidar")
    assert msg.is_bigendian
    assert np.array_equal(cloud_to_array(msg)["t"], scan["t"])


def test_padded_rows_are_skipped(backend):
    scan = ouster_scan(4, 8, seed=5)
    row = scan.view(np.uint8).reshape(4, -1)
    padded = np.concatenate([row, np.full((4, 16), 0xAB, np.uint8)], axis=1)
    msg = remake(backend, array_to_cloud(backend, scan, 0, "os_lidar"), row_step=48 * 8 + 16, data=padded.reshape(-1))
    assert cloud_to_array(msg).shape == (4, 8)
    assert np.array_equal(cloud_to_array(msg)["range"], scan["range"])
    xyz, t = cloud_to_xyz_time(msg)
    ref, keep = finite_xyz(scan)
    assert np.array_equal(xyz, ref) and np.array_equal(t, scan["t"].reshape(-1)[keep])


def test_empty_clouds(backend):
    for shape in [(0,), (3, 0)]:
        msg = array_to_cloud(backend, np.zeros(shape, OUSTER_ORIGINAL_DTYPE), 0, "os_lidar")
        assert cloud_to_array(msg).shape == shape
        xyz, t = cloud_to_xyz_time(msg)
        assert xyz.shape == (0, 3) and t.shape == (0,)


def test_is_dense_and_xyz_to_cloud(backend):
    xyz = np.arange(12, dtype=np.float64).reshape(4, 3)
    msg = xyz_to_cloud(backend, xyz, 0, "map")
    assert msg.is_dense and msg.point_step == 12 and (msg.height, msg.width) == (1, 4)
    assert np.array_equal(cloud_to_xyz(msg), xyz.astype(np.float32))
    organized = np.full((2, 3, 3), np.nan)
    organized[1, 2] = [1, 2, 3]
    msg = xyz_to_cloud(backend, organized, 0, "map")
    assert not msg.is_dense and (msg.height, msg.width) == (2, 3)
    assert np.array_equal(cloud_to_xyz(msg), [[1, 2, 3]])


def test_building_a_large_rclpy_cloud_avoids_the_per_element_setter():
    scan = np.zeros((128, 2048), OUSTER_ORIGINAL_DTYPE)
    start = time.perf_counter()
    msg = array_to_cloud(RclpyBackend(), scan, 0, "os_lidar")
    elapsed = time.perf_counter() - start
    assert len(msg.data) == 128 * 2048 * 48
    assert elapsed < 0.1, f"{elapsed:.3f} s: the data went through rclpy's per-element setter"


T = ("t", 20, 6, 1)  # the Ouster time field, which cloud_to_xyz_time reads too
# Changes to a valid 4 x 8 Ouster cloud ("data": that many zero bytes; "fields": PointField
# name, offset, datatype, count) and the reason the error must give.
MALFORMED = {
    "point_step below the fields": (
        {"point_step": 32, "row_step": 256, "data": 1024},
        "field 'range' (offset 32, 4 bytes) lies beyond point_step 32",
    ),
    "data too short": ({"data": 1535}, "len(data) 1535 != row_step 384 * height 4"),
    "data too long": ({"data": 1584}, "len(data) 1584 != row_step 384 * height 4"),
    "row_step too small": ({"row_step": 336, "data": 1344}, "row_step 336 < point_step 48 * width 8"),
    "zero point_step": ({"point_step": 0, "row_step": 0, "data": 0}, "point_step 0 must be positive"),
    "unknown datatype": ({"fields": [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 9, 1), T]}, "'z' has unknown datatype 9"),
    "field beyond point_step": ({"fields": [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 46, 7, 1), T]}, "beyond point_step"),
    "overlapping fields": ({"fields": [("x", 0, 7, 1), ("y", 2, 7, 1), ("z", 8, 7, 1), T]}, "'x' and 'y' overlap"),
    "duplicate field": ({"fields": [("x", 0, 7, 1), ("x", 4, 7, 1), ("z", 8, 7, 1), T]}, "duplicate field name 'x'"),
    "count zero": ({"fields": [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 0), T]}, "'z' has count 0"),
    "missing z": ({"fields": [("x", 0, 7, 1), ("y", 4, 7, 1), T]}, "missing field(s) ['z']"),
    "x with count 3": ({"fields": [("x", 0, 7, 3), ("y", 12, 7, 1), ("z", 16, 7, 1), T]}, "'x' has count > 1"),
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_clouds_raise_one_clear_error(backend, case):
    change, reason = dict(MALFORMED[case][0]), MALFORMED[case][1]
    if "data" in change:
        change["data"] = np.zeros(change["data"], np.uint8)
    if "fields" in change:
        change["fields"] = [point_field(backend, *f) for f in change["fields"]]
    bad = remake(backend, array_to_cloud(backend, ouster_scan(4, 8), 0, "os_lidar"), **change)
    for read in (cloud_to_xyz, cloud_to_xyz_time):
        with pytest.raises(MalformedMessageError, match=re.escape(reason)):
            read(bad)


def test_malformed_structured_read_raises_too(backend):
    good = array_to_cloud(backend, ouster_scan(4, 8), 0, "os_lidar")
    with pytest.raises(MalformedMessageError, match="len\\(data\\) 1535 != row_step 384 \\* height 4"):
        cloud_to_array(remake(backend, good, data=np.zeros(48 * 8 * 4 - 1)))
    with pytest.raises(MalformedMessageError, match="missing field\\(s\\) \\['normal'\\]"):
        cloud_dtype(good, ["x", "normal"])


@pytest.mark.parametrize(
    "points, reason",
    [
        (np.zeros((4, 3), np.float32), "structured"),
        (np.zeros(4, [("x", "<f4"), ("t", "<i8")]), "cannot represent"),
        (np.zeros(4, [("x", "<f4"), ("ok", "?")]), "cannot represent"),
        (np.zeros(4, [("x", "<f4"), ("y", ">f4")]), "mix"),
        (np.zeros((2, 2, 2), XYZ_DTYPE), "1-D or 2-D"),
    ],
    ids=["plain", "int64", "bool", "mixed-endian", "3-D"],
)
def test_unrepresentable_arrays_raise(backend, points, reason):
    with pytest.raises(MalformedMessageError, match=reason):
        array_to_cloud(backend, points, 0, "map")
