"""Held-out rig captures: making the evaluation set, and reading a capture's truth back from its bag.

The set: full-scene captures as a real session would record them (clutter,
1024 columns by default, calibration poses at the start), seeds from
:data:`lip_ros.lip.train.rigdata.EVAL_SEED_MIN` on (never used for training or
validation, whose motions also come from another generator,
``random_motion``), the rig's scenarios cycled, distances spread evenly over
the domain's range (4-20 m in STANDARD; in a shuffled order, so that distance and scenario are not tied) and
bearings within +-45 degrees.

The truth of a capture comes from its bag: ``/gt/joint_poses`` (global joint
positions and orientations, stamped with the time the pose holds), the
performer's points (the pixels ``rig_labels.npz`` labels as the performer),
and ``rig_truth.yaml`` (body scale and girth, phases, IMU calibration).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from lip_msgs_py import cloud_to_array, msg_to_pose_array, read_header
from lip_ros.bagio import read_messages
from lip_ros.core.body import BodyModel
from lip_ros.core.rotations import quat_to_matrix
from lip_ros.core.skeleton import NUM_JOINTS, Skeleton, load_skeleton
from lip_ros.lip.calibration import POSES
from lip_ros.lip.sensors import LIDAR_TOPIC
from lip_ros.lip.train.rigdata import EVAL_SEED_MIN
from lip_ros.outputs import GT_TOPICS
from lip_ros.rig.bag import LABELS_FILE, TRUTH_FILE, write_capture_bag
from lip_ros.rig.capture import CaptureConfig, CaptureSession
from lip_ros.rig.domain import DOMAINS
from lip_ros.rig.motion import SCENARIOS

__all__ = ["FIRST_SEEDS", "heldout_configs", "make_heldout_set", "find_captures", "CaptureTruth", "performer_mask",
           "load_capture"]

_MAX_BEARING_DEG = 45.0
_SINGLE_DISTANCE_M = 8.0  # a set of one capture
#: Each domain's held-out seeds start here (all >= EVAL_SEED_MIN, so no training seed); the ``shifted_<group>``
#: domains share SHIFTED's, so that their captures differ from SHIFTED's in the other groups only.
FIRST_SEEDS = {"standard": EVAL_SEED_MIN, "training": EVAL_SEED_MIN + 100_000, "shifted": EVAL_SEED_MIN + 200_000}


def heldout_configs(count: int, seconds: float = 20.0, first_seed: int | None = None,
                    columns: int = 1024, domain: str = "standard") -> list[CaptureConfig]:
    """The ``count`` capture configurations of the held-out set of ``domain`` (deterministic); seeds from
    ``first_seed`` (default: the domain's own, :data:`FIRST_SEEDS`)."""
    first_seed = FIRST_SEEDS.get(domain, FIRST_SEEDS["shifted"]) if first_seed is None else first_seed
    if first_seed < EVAL_SEED_MIN:
        raise ValueError(f"held-out seeds start at {EVAL_SEED_MIN}, not {first_seed}")
    d = DOMAINS[domain]
    rng = np.random.default_rng([first_seed, count])
    single = np.array([float(np.clip(_SINGLE_DISTANCE_M, *d.distance_m))])
    distances = rng.permutation(np.linspace(*d.distance_m, count)) if count > 1 else single
    bearings = rng.uniform(-_MAX_BEARING_DEG, _MAX_BEARING_DEG, count)
    mount = np.random.default_rng([first_seed, count, 1])
    return [
        CaptureConfig(scenario=SCENARIOS[i % len(SCENARIOS)], seconds=seconds, seed=first_seed + i,
                      distance_m=round(float(distances[i]), 1), bearing_deg=round(float(bearings[i]), 1),
                      columns=columns, domain=domain,
                      lidar_height_m=round(float(mount.uniform(*d.lidar_height_m)), 2),
                      lidar_pitch_deg=round(float(mount.uniform(*d.lidar_pitch_deg)), 1),
                      imu_heading_spread_deg=d.imu_heading_spread_deg, imu_latency_ms=d.imu_latency_ms)
        for i in range(count)
    ]


def _bag_name(config: CaptureConfig) -> str:
    return f"{config.seed}_{config.scenario}_{config.distance_m:g}m"


def make_heldout_set(out: Path, configs: list[CaptureConfig], progress: bool = True) -> list[Path]:
    """Record each configuration as a bag under ``out`` (bags that exist already are kept); their paths."""
    out.mkdir(parents=True, exist_ok=True)
    bags = []
    for config in configs:
        bag = out / _bag_name(config)
        if not (bag / TRUTH_FILE).is_file():
            if bag.exists():
                raise FileExistsError(f"{bag} exists but is incomplete; remove it")
            write_capture_bag(CaptureSession(config), bag, progress=progress)
            if progress:
                print(f"lip_eval: recorded {bag}", file=sys.stderr, flush=True)
        bags.append(bag)
    return bags


def find_captures(paths: list[Path]) -> list[Path]:
    """Rig bags among ``paths``: each is a rig bag directory or a directory holding such bags."""
    bags = []
    for path in paths:
        if (path / TRUTH_FILE).is_file():
            bags.append(path)
        elif path.is_dir():
            bags.extend(sorted(p for p in path.iterdir() if (p / TRUTH_FILE).is_file()))
        else:
            raise FileNotFoundError(f"{path}: not a rig bag (no {TRUTH_FILE}) or a directory of rig bags")
    if not bags:
        raise FileNotFoundError(f"no rig bags (directories with {TRUTH_FILE}) in {', '.join(map(str, paths))}")
    return bags


@dataclass(frozen=True, eq=False)
class CaptureTruth:
    """What the rig knows about one recorded capture."""

    bag: Path
    scenario: str
    distance_m: float
    rate_hz: float
    skeleton: Skeleton  # the performer's (scaled contract skeleton)
    body: BodyModel  # the performer's capsule body
    motion_start_ns: int  # end of the calibration poses: frames whose truth holds from here on are scored
    frame_stamp_ns: np.ndarray  # (K,) header stamps of the LiDAR frames
    truth_stamp_ns: np.ndarray  # (K,) when each frame's truth holds (frame stamp + mean performer point time)
    gt_stamp_ns: np.ndarray  # (G,) stamps of /gt/joint_poses, ascending
    gt_glob_rot: np.ndarray  # (G, 24, 3, 3)
    gt_joint_pos: np.ndarray  # (G, 24, 3)
    performer_points: list[np.ndarray]  # per frame (N_k, 3) float32: the returns labelled as the performer
    labels: dict[str, np.ndarray]  # the rig_labels.npz arrays
    truth: dict  # rig_truth.yaml

    @property
    def name(self) -> str:
        """The bag directory's name."""
        return self.bag.name

    def frame_index(self, frame_stamp_ns: int) -> int | None:
        """Index of the frame with this header stamp, None if there is none."""
        k = int(np.searchsorted(self.frame_stamp_ns, frame_stamp_ns))
        return k if k < len(self.frame_stamp_ns) and self.frame_stamp_ns[k] == frame_stamp_ns else None


def performer_mask(labels: dict[str, np.ndarray], k: int) -> np.ndarray:
    """(H, W) bool: the pixels of frame ``k`` that ``rig_labels.npz`` labels as the performer."""
    offsets, pixel, actor = labels["offsets"], labels["pixel"], labels["actor"]
    mask = np.zeros(int(np.prod(labels["shape"])), dtype=bool)
    rows = slice(offsets[k], offsets[k + 1])
    mask[pixel[rows][actor[rows] == 0]] = True
    return mask.reshape(tuple(labels["shape"]))


def load_capture(bag: Path) -> CaptureTruth:
    """Read a rig bag's sidecars, ground truth and performer points."""
    bag = Path(bag)
    with open(bag / TRUTH_FILE, encoding="utf-8") as f:
        truth = yaml.safe_load(f)
    with np.load(bag / LABELS_FILE) as npz:
        labels = {k: npz[k] for k in npz.files}
    performer = truth["performer"]
    skeleton = load_skeleton().with_proportions(performer.get("proportions", {})).scaled(
        float(performer["body_scale"]))
    phases = {p["name"]: (int(p["start_ns"]), int(p["end_ns"])) for p in truth["phases"]}
    frames = {int(s): k for k, s in enumerate(labels["frame_stamp_ns"])}
    points: list[np.ndarray] = [np.zeros((0, 3), np.float32)] * len(frames)
    gt_stamp, gt_rot, gt_pos = [], [], []
    for m in read_messages(bag, [LIDAR_TOPIC, GT_TOPICS.joint_poses]):
        if m.topic == LIDAR_TOPIC:
            k = frames.get(read_header(m.msg)[0])
            if k is not None:
                cloud = cloud_to_array(m.msg, ["x", "y", "z"])[performer_mask(labels, k)]
                xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float32)
                points[k] = xyz[np.isfinite(xyz).all(axis=1)]
        else:
            poses = msg_to_pose_array(m.msg, NUM_JOINTS)
            gt_stamp.append(poses.stamp_ns)
            gt_rot.append(quat_to_matrix(poses.quats))
            gt_pos.append(poses.positions)
    order = np.argsort(gt_stamp, kind="stable")
    return CaptureTruth(
        bag=bag,
        scenario=str(performer["scenario"]),
        distance_m=float(truth["config"]["distance_m"]),
        rate_hz=float(truth["lidar"]["rate_hz"]),
        skeleton=skeleton,
        body=BodyModel(skeleton, girth=float(performer["girth"]), torso_girth=float(performer.get("torso_girth", 1.0)),
                       limb_girth=float(performer.get("limb_girth", 1.0))),
        motion_start_ns=max(phases[p][1] for p in POSES),
        frame_stamp_ns=labels["frame_stamp_ns"],
        truth_stamp_ns=labels["truth_stamp_ns"],
        gt_stamp_ns=np.asarray(gt_stamp, dtype=np.int64)[order],
        gt_glob_rot=np.asarray(gt_rot).reshape(-1, NUM_JOINTS, 3, 3)[order],
        gt_joint_pos=np.asarray(gt_pos).reshape(-1, NUM_JOINTS, 3)[order],
        performer_points=points,
        labels=labels,
        truth=truth,
    )
