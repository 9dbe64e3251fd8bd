"""What the HSC4D trajectory needs to go on after its process restarts, without another jump (ROS-free).

A trajectory node that is killed and started again mid-capture would otherwise
wait for a jump that the performer will not make again. :class:`TrajectoryResume`
holds what the jump and the first seconds gave: the suit's clock offset, the
mounting as it was levelled, turned and moved since, the suit's stride scale,
the pelvis gyro's bias (measured in the A-pose: a restarted wearer need not
stand still again; a file without it, written before session 52, resumes
with none until the wearer stands still), the last fused pelvis pose with
the suit's own pelvis pose at the same moment (in the suit's world), and the
odometry's local map round it.
:meth:`lip_ros.hsc4d.trajectory.TrajectoryPipeline.resume` starts a new
trajectory from it: the first sweep is predicted where the suit's motion since
the saved pose puts the pelvis (the suit knows no stairs: its height is the
saved one) and registered against the saved local map, in the same ``map``
frame; the site map (``/hsc4d/map``) starts again empty.
This holds while the suit's odometry goes on in the same world across the
restart (its driver was not restarted) and both clocks keep their offset; the
node refuses a file whose pose is older than its ``resume_max_gap_s``, or
newer than the first sweep, and waits for the jump instead.

:func:`save_resume` writes YAML atomically (a crash never leaves half a file);
:func:`load_resume` checks it.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import yaml

__all__ = ["TrajectoryResume", "save_resume", "load_resume", "map_file", "resume_refusal"]

_KIND = "lip_ros hsc4d trajectory resume"
_NUMBERS = ("stride_scale", "pelvis_height_m", "mount_levelled_deg", "mount_yaw_deg", "suit_yaw_rad")  # floats
_VERSION = 1


@dataclass(frozen=True, eq=False)
class TrajectoryResume:
    """The state a trajectory resumes from (poses (4, 4), stamps on the LiDAR's clock)."""

    stamp_ns: int  # reference time of the last output
    offset_ns: int  # the suit's clock offset (suit stamp = LiDAR stamp + offset)
    T_M_L: np.ndarray  # the mounting in use: the LiDAR in the pelvis frame
    T_map_P: np.ndarray  # the last fused pelvis pose in map
    T_I_P: np.ndarray  # the suit's own pelvis pose at the same time, in the suit's world
    stride_scale: float  # the suit's stride scale (LiDAR per suit)
    pelvis_height_m: float  # the map frame's first pelvis height above the ground
    mount_levelled_deg: float  # how far levelling turned the nominal mounting (for the diagnostics)
    mount_yaw_deg: float  # how far walking turned it since (for the diagnostics)
    map_points: np.ndarray  # (M, 3) float32 the odometry's local map in map
    suit_yaw_rad: float  # the heading of the suit's world in map (its path turned onto the fused one)
    gyro_bias_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the pelvis gyro's bias (3,)
    gyro_bias_still_s: float = 0.0  # the still time it was measured over (0: not measured)

    def __post_init__(self) -> None:
        for name in ("T_M_L", "T_map_P", "T_I_P"):
            T = np.asarray(getattr(self, name), dtype=np.float64)
            if T.shape != (4, 4) or not np.isfinite(T).all() or not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]) \
                    or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
                raise ValueError(f"{name} is not a rigid transform (4 x 4): {T.tolist()}")
            object.__setattr__(self, name, T)
        if not (np.isfinite(self.stride_scale) and self.stride_scale > 0.0 and np.isfinite(self.pelvis_height_m)
                and np.isfinite(self.suit_yaw_rad)):
            raise ValueError(f"stride scale {self.stride_scale} (> 0) or pelvis height {self.pelvis_height_m} not "
                             "valid")
        bias = np.asarray(self.gyro_bias_rad_s, dtype=np.float64)
        if bias.shape != (3,) or not np.isfinite(bias).all() or not 0.0 <= self.gyro_bias_still_s < np.inf:
            raise ValueError(f"gyro bias {bias.tolist()} (3 finite rad/s) or its still time {self.gyro_bias_still_s} "
                             "(finite, >= 0 s) not valid")
        object.__setattr__(self, "gyro_bias_rad_s", bias)
        points = np.asarray(self.map_points, dtype=np.float32)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise ValueError(f"map points must be finite (M, 3), got shape {points.shape}")
        object.__setattr__(self, "map_points", points)

    def as_dict(self) -> dict[str, Any]:
        """The YAML document (the map points go in a file of their own)."""
        return {"kind": _KIND, "version": _VERSION, "stamp_ns": int(self.stamp_ns), "offset_ns": int(self.offset_ns),
                **{k: np.asarray(getattr(self, k)).tolist() for k in ("T_M_L", "T_map_P", "T_I_P")},
                **{k: float(getattr(self, k)) for k in _NUMBERS},
                "gyro_bias_rad_s": self.gyro_bias_rad_s.tolist(), "gyro_bias_still_s": float(self.gyro_bias_still_s),
                "map_points": len(self.map_points)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any], map_points: np.ndarray) -> TrajectoryResume:
        """From :meth:`as_dict`'s document and the map points; ValueError if it is not one."""
        _check_kind(doc)
        return cls(stamp_ns=int(doc["stamp_ns"]), offset_ns=int(doc["offset_ns"]),
                   **{k: np.array(doc[k], dtype=np.float64) for k in ("T_M_L", "T_map_P", "T_I_P")},
                   **{k: float(doc[k]) for k in _NUMBERS},
                   gyro_bias_rad_s=np.array(doc.get("gyro_bias_rad_s", [0.0, 0.0, 0.0]), dtype=np.float64),
                   gyro_bias_still_s=float(doc.get("gyro_bias_still_s", 0.0)),
                   map_points=map_points)


def resume_refusal(state: TrajectoryResume, first_ns: int, max_gap_s: float) -> str | None:
    """Why a graph whose first sweep (or fused pose) is stamped ``first_ns`` does not go on from ``state``: it is
    more than ``max_gap_s`` older, or not older (another capture, another clock); None if it does."""
    gap_s = (first_ns - state.stamp_ns) * 1e-9
    if 0.0 < gap_s <= max_gap_s:
        return None
    return f"the saved state is {gap_s:+.1f} s from the first sweep (it must be 0-{max_gap_s:g} s before it)"


def _check_kind(doc: Any) -> None:
    if not isinstance(doc, dict) or doc.get("kind") != _KIND or doc.get("version") != _VERSION:
        raise ValueError(f"not a {_KIND} (version {_VERSION}) document")


def map_file(path: str | Path) -> Path:
    """Where the map points of the state at ``path`` go: ``<path>.map.npz`` (with the state's stamp)."""
    path = Path(path)
    return path.with_name(path.name + ".map.npz")


def _replace_atomically(path: Path, write: Callable[[BinaryIO], None]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        write(f)
    os.replace(tmp, path)


def save_resume(state: TrajectoryResume, path: str | Path) -> None:
    """Write ``state`` to ``path`` (YAML) and its map points with its stamp to :func:`map_file` (NumPy), each
    atomically, the points first (a stop in between leaves points whose stamp is not the state's)."""
    path = Path(path)
    _replace_atomically(map_file(path), lambda f: np.savez(f, points=state.map_points,
                                                           stamp_ns=np.int64(state.stamp_ns)))
    _replace_atomically(path, lambda f: f.write(yaml.safe_dump(state.as_dict(), sort_keys=False).encode("utf-8")))


def load_resume(path: str | Path, with_map: bool = True) -> TrajectoryResume:
    """Read a state written by :func:`save_resume` (``with_map`` False: without its map points, which are then
    empty); ValueError if it is not one, or cannot be read whole (missing, truncated, its points another
    state's)."""
    try:
        doc = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
        _check_kind(doc)
        points = np.zeros((0, 3), dtype=np.float32)
        if with_map:
            with np.load(map_file(path), allow_pickle=False) as saved:
                if int(saved["stamp_ns"]) != doc["stamp_ns"] or len(saved["points"]) != doc["map_points"]:
                    raise ValueError(f"{map_file(path).name} holds the map of another state")
                points = saved["points"]
        return TrajectoryResume.from_dict(doc, points)
    except Exception as exc:  # noqa: BLE001 - whatever a broken file raises (OSError, EOFError, zipfile, YAML...)
        raise ValueError(f"{path} is not a whole {_KIND} file: {exc}") from exc
