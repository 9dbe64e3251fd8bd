"""The oracle front end: the rig's true performer labels and IMU calibration in place of segmentation and
the online calibration, so that evaluation can tell network errors from front-end errors."""

from __future__ import annotations

import numpy as np

from lip_ros.core.frames import level_rotation
from lip_ros.lip.calibration import Calibration
from lip_ros.lip.evaluation.captures import CaptureTruth, performer_mask
from lip_ros.lip.segmentation import SegmentationResult, SegmentationStatus

__all__ = ["LabelSegmenter", "truth_calibration", "true_level"]


class LabelSegmenter:
    """A :class:`lip_ros.lip.pipeline.Segmenter` that returns the pixels the rig labelled as the performer."""

    def __init__(self, capture: CaptureTruth) -> None:
        self.capture = capture

    @property
    def level(self) -> np.ndarray | None:
        """R_L_P of the rig's LiDAR, from its true tilt (None for bags from before the rig recorded it)."""
        return true_level(self.capture)

    def process(self, points: np.ndarray, stamp_ns: int) -> SegmentationResult:
        """The labelled performer of the frame stamped ``stamp_ns``; MALFORMED for a frame the rig did not make."""
        k = self.capture.frame_index(stamp_ns)
        if k is None or points.shape != tuple(self.capture.labels["shape"]):
            return SegmentationResult(SegmentationStatus.MALFORMED, "not a frame of this capture", int(stamp_ns),
                                      np.zeros(points.shape, dtype=bool), np.zeros((0, 3), np.float32),
                                      np.zeros(0, np.uint32), None)
        mask = performer_mask(self.capture.labels, k) & (points["range"] > 0)
        picked = points[mask]
        xyz = np.stack([picked["x"], picked["y"], picked["z"]], axis=1).astype(np.float32)
        status = SegmentationStatus.OK if len(xyz) else SegmentationStatus.NO_PERFORMER
        position = xyz[:, :2].mean(axis=0).astype(np.float64) if len(xyz) else None
        return SegmentationResult(status, "" if len(xyz) else "performer not scanned", int(stamp_ns), mask, xyz,
                                  picked["t"].astype(np.uint32), position)


def true_level(capture: CaptureTruth) -> np.ndarray | None:
    """R_L_P (3, 3): the level frame of the rig's LiDAR from its true tilt; None if the bag does not record it."""
    R_S_L = capture.truth["lidar"].get("R_S_L")
    return None if R_S_L is None else level_rotation(np.asarray(R_S_L, dtype=np.float64).T @ [0.0, 0.0, 1.0])


def truth_calibration(capture: CaptureTruth) -> Calibration:
    """The rig's true IMU calibration (R_L_I, each R_B_S) as a :class:`Calibration` in the LiDAR's level frame
    (:func:`true_level`), as the pipeline uses it; the calibrating body's frame is the true pelvis orientation at
    the first ground-truth pose."""
    imu = capture.truth["imu_calibration"]
    R_L_P = true_level(capture)
    R_P_L = np.eye(3) if R_L_P is None else R_L_P.T
    R_P_I = R_P_L @ np.asarray(imu["R_L_I"], dtype=np.float64)
    R_P_M = R_P_L @ capture.gt_glob_rot[0, 0]
    names = list(imu["sensors"])
    return Calibration(
        R_L_I=R_P_I,  # a Calibration's "L" is the level frame P
        R_B_S={n: np.asarray(imu["sensors"][n]["R_B_S"], dtype=np.float64) for n in names},
        R_I_M=R_P_I.T @ R_P_M,
        heading=float(np.arctan2(R_P_M[1, 2], R_P_M[0, 2])),
        heading_source="truth",
        windows={},
        residual_deg=dict.fromkeys(names, 0.0),
        spread_deg=dict.fromkeys(names, 0.0),
        tilt_deg=0.0,
    )
