"""visualization_msgs/MarkerArray of a skeleton: bones as one LINE_LIST, joints as one SPHERE_LIST."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lip_msgs_py._validate import finite_array
from lip_msgs_py.backend import Backend
from lip_msgs_py.errors import MalformedMessageError
from lip_msgs_py.geometry import point_msg, pose_msg

__all__ = ["LINE_LIST", "SPHERE_LIST", "ADD", "BONES_ID", "JOINTS_ID", "SKELETON_NS", "SKELETON_COLOR", "LINE_WIDTH_M",
           "JOINT_DIAMETER_M", "IDENTITY_POSE", "MarkerSpec", "skeleton_to_markers", "skeleton_marker_specs"]

#: visualization_msgs/Marker constants used here.
LINE_LIST, SPHERE_LIST, ADD = 5, 7, 0
#: Marker ids of the bones and the joints within the namespace.
BONES_ID, JOINTS_ID = 0, 1
#: Defaults of a skeleton's markers: namespace, RGBA colour, bone line width and joint sphere diameter (m).
SKELETON_NS = "skeleton"
SKELETON_COLOR = (0.2, 0.6, 1.0, 1.0)
LINE_WIDTH_M = 0.02
JOINT_DIAMETER_M = 0.05

#: The markers' pose: their points are in the header's frame as they are (position, xyzw quaternion).
IDENTITY_POSE = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))


def _marker_color(rgba: Sequence[float]) -> np.ndarray:
    """A validated RGBA colour (4,), each in [0, 1]."""
    c = finite_array(rgba, (4,), "marker colour")
    if ((c < 0.0) | (c > 1.0)).any():
        raise MalformedMessageError(f"marker colour {c.tolist()} outside [0, 1]")
    return c


@dataclass(frozen=True)
class MarkerSpec:
    """What varies between a skeleton's markers: id, type, scale (line width or sphere diameter), RGBA, points."""

    marker_id: int
    kind: int
    scale: float
    rgba: np.ndarray  # (4,) validated
    points: np.ndarray  # (M, 3)


def skeleton_marker_specs(positions: Any, parents: Any, color: Sequence[float], joint_color: Sequence[float] | None,
                          line_width: float, joint_diameter: float) -> tuple[MarkerSpec, MarkerSpec]:
    """The bones (a LINE_LIST from each joint's parent to it, ``parents[j] < 0``: root) and the joints (a
    SPHERE_LIST) of a skeleton's markers, validated; the arguments as :func:`skeleton_to_markers`'."""
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
    return (MarkerSpec(BONES_ID, LINE_LIST, float(line_width), _marker_color(color), bone_ends),
            MarkerSpec(JOINTS_ID, SPHERE_LIST, float(joint_diameter),
                       _marker_color(color if joint_color is None else joint_color), p))


def skeleton_to_markers(
    backend: Backend,
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
) -> Any:
    """MarkerArray: bone lines from each joint to its parent (``parents[j] < 0``: root) and joint spheres.

    ``positions`` (J, 3) in ``frame_id``; colours are RGBA in [0, 1] (``joint_color`` None: ``color``);
    ``lifetime_ns`` 0 keeps the markers until replaced.
    """
    specs = skeleton_marker_specs(positions, parents, color, joint_color, line_width, joint_diameter)
    header = backend.header(stamp_ns, frame_id)
    lifetime = backend.duration(lifetime_ns)

    def marker(m: MarkerSpec) -> Any:
        r, g, b, a = (float(v) for v in m.rgba)
        return backend.msg(
            "visualization_msgs/msg/Marker",
            header=header,
            ns=str(ns),
            id=m.marker_id,
            type=m.kind,
            action=ADD,
            pose=pose_msg(backend, *IDENTITY_POSE),
            scale=backend.msg("geometry_msgs/msg/Vector3", x=m.scale, y=m.scale, z=m.scale),
            color=backend.msg("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a),
            lifetime=lifetime,
            points=[point_msg(backend, q) for q in m.points],
        )

    return backend.msg("visualization_msgs/msg/MarkerArray", markers=[marker(m) for m in specs])
