"""Sizes and loss weights of the LIP networks, as a frozen dataclass that round-trips through JSON."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

__all__ = ["VARIANTS", "LipConfig", "TRAINING_RATE_HZ"]

#: The method and the paper's ablations (its tables 3, 6 and 7), each trained on its own:
#: ``full`` the method; ``lidar_only`` / ``imu_only`` the same networks with the other modality's input
#: zeroed; ``no_prior`` (the paper's "w/o RE") the prior encoder's temporal features go straight into the
#: second stage with the IMUs, no prior joints or root orientation; ``no_joint_map`` ("w/o JE") the
#: body-pose estimator works on the prior and the IMUs, no refined joint map; ``trans_no_pose`` ("w/o PG")
#: the translation corrector sees its point features only.
VARIANTS = ("full", "lidar_only", "imu_only", "no_prior", "no_joint_map", "trans_no_pose")


#: The LiDAR rate of the training sequences (``lip_ros.lip.train.rigdata``), which ``LipConfig.rate_hz`` records.
TRAINING_RATE_HZ = 10.0


@dataclass(frozen=True)
class LipConfig:
    """Network sizes and loss weights.

    ``point_widths`` is the per-point MLP of a PointNet (its last width is the
    frame feature size k); ``prior_hidden`` / ``prior_layers`` the GRU of the
    pose-prior encoder, ``decoder_hidden`` its MLP decoder; ``estimator_hidden``
    the width of the three GRUs of each hierarchical estimator; ``trans_*`` the
    translation corrector's own PointNet-GRU encoder and fusion MLP.
    ``bidirectional`` = the paper's offline bi-GRUs (no streaming).
    ``lambdas`` weigh the joint-prior, orientation-prior, refined-joint,
    rotation and forward-kinematics losses (equations 3 and 7): the paper's
    1, 1, 0.2, 0.7, 0.7 with the two prior weights cut to 0.1 (measured,
    docs/lip/training.md "Loss weights").
    ``variant`` is the method (``full``) or one of its ablations (:data:`VARIANTS`).
    ``rate_hz`` is the LiDAR rate of the sequences it was trained on (the rig's 10 Hz; weights saved before
    it was recorded load with that): a faster LiDAR is fed to it as interleaved sequences at this rate
    (:class:`lip_ros.lip.nets.lip_model.LipModel`).
    """

    num_points: int = 256
    point_widths: tuple[int, ...] = (32, 64, 128)
    prior_hidden: int = 192
    prior_layers: int = 2
    decoder_hidden: int = 192
    estimator_hidden: int = 192
    trans_point_widths: tuple[int, ...] = (16, 32, 64)
    trans_hidden: int = 64
    bidirectional: bool = False
    lambdas: tuple[float, float, float, float, float] = (0.1, 0.1, 0.2, 0.7, 0.7)
    variant: str = "full"
    rate_hz: float = TRAINING_RATE_HZ

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ValueError(f"LipConfig rate_hz must be > 0, got {self.rate_hz}")
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown LipConfig variant {self.variant!r}; one of {', '.join(VARIANTS)}")

    @classmethod
    def paper(cls) -> LipConfig:
        """The paper's sizes and loss weights: PointNet 64-128-1024, bi-GRU 2 x 512, MLP decoder 512, both
        encoders alike; lambdas 1, 1, 0.2, 0.7, 0.7."""
        return cls(
            point_widths=(64, 128, 1024),
            prior_hidden=1024,
            decoder_hidden=512,
            estimator_hidden=512,
            trans_point_widths=(64, 128, 1024),
            trans_hidden=1024,
            bidirectional=True,
            lambdas=(1.0, 1.0, 0.2, 0.7, 0.7),
        )

    @classmethod
    def tiny(cls) -> LipConfig:
        """A few thousand parameters, for smoke tests."""
        return cls(
            num_points=32,
            point_widths=(16, 32),
            prior_hidden=32,
            prior_layers=1,
            decoder_hidden=32,
            estimator_hidden=32,
            trans_point_widths=(16, 16),
            trans_hidden=16,
        )

    def with_(self, **changes: object) -> LipConfig:
        """A copy with some fields changed."""
        return replace(self, **changes)

    def to_dict(self) -> dict:
        """Plain JSON types."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> LipConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown LipConfig keys {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    def save(self, path: str | Path) -> None:
        """Write as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path) -> LipConfig:
        """Read a JSON file written by :meth:`save`."""
        return cls.from_dict(json.loads(Path(path).read_text(encoding="utf-8")))
