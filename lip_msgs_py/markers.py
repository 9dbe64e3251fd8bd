"""visualization_msgs/MarkerArray of a skeleton: bones as one LINE_LIST, joints as one SPHERE_LIST."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lip_msgs_py._validate import finite_array
from lip_msgs_py.backend import Backend
from lip_msgs_py.errors import MalformedMessageError
from lip_msgs_py.geometry import point_msg, pose_msg

__all__ = ["LINE_LIST", "SPHERE_LIST", "ADD", "BONES_ID", "JOINTS_ID", "skeleton_to_markers"]

#: visualization_msgs/Marker constants used here.
LINE_LIST, SPHERE_LIST, ADD = 5, 7, 0
#: Marker ids of the bones and the joints within the namespace.
BONES_ID, JOINTS_ID = 0, 1

_IDENTITY_POSE = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))


def _color(backend: Backend, rgba: Sequence[float]) -> Any:
    c = finite_array(rgba, (4,), "marker colour")
    if ((c < 0.0) | (c > 1.0)).any():
        raise MalformedMessageError(f"marker colour {c.tolist()} outside [0, 1]")
    return backend.msg("std_msgs/msg/ColorRGBA", r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))


def skeleton_to_markers(
    backend: Backend,
    stamp_ns: int,
    frame_id: str,
    positions: Any,
    parents: Any,
    ns: str = "skeleton",
    color: Sequence[float] = (0.2, 0.6, 1.0, 1.0),
    joint_color: Sequence[float] | None = None,
    line_width: float = 0.02,
    joint_diameter: float = 0.05,
    lifetime_ns: int = 0,
) -> Any:
    """MarkerArray: bone lines from each joint to its parent (``parents[j] < 0``: root) and joint spheres.

    ``positions`` (J, 3) in ``frame_id``; colours are RGBA in [0, 1] (``joint_color`` None: ``color``);
    ``lifetime_ns`` 0 keeps the markers until replaced.
    """
    p = finite_array(positions, (None, 3), "skeleton positions")
    parents = np.asarray(parents)
    if parents.shape != (len(p),) or parents.dtype.kind not in "iu" or (parents >= len(p)).any():
        raise MalformedMessageError(
            f"parents must be {len(p)} integer indices < {len(p)} (negative: root), got {parents.tolist()}"
        )
    if not (line_width > 0.0 and joint_diameter > 0.0):
        raise MalformedMessageError(f"line_width {line_width} and joint_diameter {joint_diameter} must be positive")
    children = np.flatnonzero(parents >= 0)
    bone_ends = np.stack([p[parents[children]], p[children]], axis=1).reshape(-1, 3)
    header = backend.header(stamp_ns, frame_id)
    lifetime = backend.duration(lifetime_ns)

    def marker(marker_id: int, kind: int, scale: float, rgba: Sequence[float], points: np.ndarray) -> Any:
        return backend.msg(
            "visualization_msgs/msg/Marker",
            header=header,
            ns=str(ns),
            id=marker_id,
            type=kind,
            action=ADD,
            pose=pose_msg(backend, *_IDENTITY_POSE),
            scale=backend.msg("geometry_msgs/msg/Vector3", x=float(scale), y=float(scale), z=float(scale)),
            color=_color(backend, rgba),
            lifetime=lifetime,
            points=[point_msg(backend, q) for q in points],
        )

    return backend.msg(
        "visualization_msgs/msg/MarkerArray",
        markers=[
            marker(BONES_ID, LINE_LIST, line_width, color, bone_ends),
            marker(JOINTS_ID, SPHERE_LIST, joint_diameter, color if joint_color is None else joint_color, p),
        ],
    )
