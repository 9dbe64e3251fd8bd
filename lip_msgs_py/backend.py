"""Message construction for rclpy message classes and rosbags message objects.

Readers in this package are duck-typed (both kinds of message have the same
attribute names). Writers take a backend, whose ``msg(type_name, **fields)``
builds e.g. ``'sensor_msgs/msg/PointCloud2'``. Numeric arrays and sequences may
be given as numpy arrays for either backend: rclpy gets them copied into its
``array.array`` / ``numpy`` members with one memcpy (its own setters iterate
element by element), rosbags gets owned numpy arrays of the declared dtype.
"""

from __future__ import annotations

import array
import importlib
from abc import ABC, abstractmethod
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.interfaces import Nodetype

from lip_msgs_py.errors import MalformedMessageError
from lip_msgs_py.stamps import ns_to_sec_nanosec

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = ["Backend", "RclpyBackend", "RosbagsBackend", "rclpy_message_class"]

#: Non-zero default values declared in the .msg files of the interfaces used with
#: rosbags (its typestore drops them; rclpy applies them), so both backends agree.
_MSG_DEFAULTS: dict[str, dict[str, Any]] = {
    "geometry_msgs/msg/Quaternion": {"w": 1.0},
    "sensor_msgs/msg/NavSatStatus": {"status": -2},
}


class Backend(ABC):
    """Builds, serializes and deserializes messages of one Python message flavour."""

    @abstractmethod
    def msg(self, type_name: str, **fields: Any) -> Any:
        """A message of ``type_name`` ('pkg/msg/Name'); omitted fields take their defaults."""

    @abstractmethod
    def serialize(self, msg: Any, type_name: str) -> bytes:
        """CDR bytes of ``msg`` (with the 4-byte encapsulation header, as in rosbag2)."""

    @abstractmethod
    def deserialize(self, raw: bytes, type_name: str) -> Any:
        """The message of ``type_name`` encoded in the CDR bytes ``raw``."""

    def time(self, ns: int) -> Any:
        """``builtin_interfaces/msg/Time`` of integer nanoseconds."""
        sec, nanosec = ns_to_sec_nanosec(ns)
        return self.msg("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)

    def duration(self, ns: int) -> Any:
        """``builtin_interfaces/msg/Duration`` of integer nanoseconds."""
        sec, nanosec = ns_to_sec_nanosec(ns)
        return self.msg("builtin_interfaces/msg/Duration", sec=sec, nanosec=nanosec)

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        """``std_msgs/msg/Header``."""
        return self.msg("std_msgs/msg/Header", stamp=self.time(stamp_ns), frame_id=str(frame_id))


@cache
def rclpy_message_class(type_name: str) -> type:
    """The rclpy class of ``type_name`` ('pkg/msg/Name'); KeyError if its Python package is not installed."""
    try:
        package, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ValueError, ImportError, AttributeError) as exc:
        raise KeyError(f"unknown message type {type_name!r} ({exc})") from None


class RclpyBackend(Backend):
    """rclpy message classes (the generated ``<pkg>.msg`` modules).

    ``check_fields`` is passed to every message constructed (None: rclpy's
    default, from ROS_PYTHON_CHECK_FIELDS); True makes rclpy assert every field's type.
    """

    def __init__(self, check_fields: bool | None = None) -> None:
        self._ctor_kwargs = {} if check_fields is None else {"check_fields": check_fields}

    def msg(self, type_name: str, **fields: Any) -> Any:
        m = rclpy_message_class(type_name)(**self._ctor_kwargs)
        for name, value in fields.items():
            try:
                current = getattr(m, name)
            except AttributeError:
                raise TypeError(f"{type_name} has no field {name!r}") from None
            if isinstance(current, array.array):  # unbounded numeric sequence: one memcpy
                current.frombytes(np.ascontiguousarray(value, dtype=current.typecode).reshape(-1).view(np.uint8))
            elif isinstance(current, np.ndarray):  # fixed-size numeric array
                value = np.asarray(value, dtype=current.dtype)
                if value.size != current.size:
                    raise MalformedMessageError(f"{type_name}.{name} needs {current.size} values, got {value.size}")
                setattr(m, name, value.reshape(current.shape))
            elif isinstance(current, bytes) and isinstance(value, int):  # 'byte' fields
                setattr(m, name, bytes([value]))
            else:
                setattr(m, name, value)
        return m

    def serialize(self, msg: Any, type_name: str) -> bytes:
        from rclpy.serialization import serialize_message

        return serialize_message(msg)

    def deserialize(self, raw: bytes, type_name: str) -> Any:
        from rclpy.serialization import deserialize_message

        return deserialize_message(raw, rclpy_message_class(type_name))


class RosbagsBackend(Backend):
    """rosbags message dataclasses of a typestore (default: ROS 2 Jazzy)."""

    def __init__(self, typestore: Typestore | None = None) -> None:
        if typestore is None:
            from rosbags.typesys import Stores, get_typestore

            typestore = get_typestore(Stores.ROS2_JAZZY)
        self.typestore = typestore

    def msg(self, type_name: str, **fields: Any) -> Any:
        try:
            cls = self.typestore.types[type_name]
            _, fielddefs = self.typestore.fielddefs[type_name]
        except KeyError:
            raise KeyError(f"unknown message type {type_name!r}") from None
        unknown = fields.keys() - {name for name, _ in fielddefs}
        if unknown:
            raise TypeError(f"{type_name} has no field(s) {sorted(unknown)}")
        fields = {**_MSG_DEFAULTS.get(type_name, {}), **fields}
        return cls(
            **{
                name: self._value(desc, fields[name], f"{type_name}.{name}") if name in fields else self._default(desc)
                for name, desc in fielddefs
            }
        )

    def serialize(self, msg: Any, type_name: str) -> bytes:
        return bytes(self.typestore.serialize_cdr(msg, type_name))

    def deserialize(self, raw: bytes, type_name: str) -> Any:
        return self.typestore.deserialize_cdr(raw, type_name)

    @staticmethod
    def _numeric_dtype(desc: Any) -> np.dtype | None:
        """numpy dtype of an array/sequence field of a numeric base type, else None."""
        if desc[0] not in (Nodetype.ARRAY, Nodetype.SEQUENCE) or desc[1][0][0] != Nodetype.BASE:
            return None
        base = desc[1][0][1][0]
        if base in ("string", "wstring"):
            return None
        return np.dtype({"bool": "bool", "byte": "uint8", "char": "uint8", "octet": "uint8"}.get(base, base))

    def _value(self, desc: Any, value: Any, what: str) -> Any:
        dtype = self._numeric_dtype(desc)
        if dtype is None:
            return value
        value = np.array(value, dtype=dtype).reshape(-1)
        if desc[0] == Nodetype.ARRAY and value.size != desc[1][1]:
            raise MalformedMessageError(f"{what} needs {desc[1][1]} values, got {value.size}")
        return value

    def _default(self, desc: Any) -> Any:
        kind, rest = desc
        if kind == Nodetype.BASE:
            base = rest[0]
            if base in ("string", "wstring"):
                return ""
            if base == "bool":
                return False
            return 0.0 if base.startswith("float") else 0
        if kind == Nodetype.NAME:
            return self.msg(rest)
        dtype = self._numeric_dtype(desc)
        length = rest[1] if kind == Nodetype.ARRAY else 0
        if dtype is not None:
            return np.zeros(length, dtype=dtype)
        return [self._default(rest[0]) for _ in range(length)]
