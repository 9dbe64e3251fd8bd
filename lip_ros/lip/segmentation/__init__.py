"""Performer segmentation for a static Ouster (LIP): the calibrated performer's points in each organized cloud.

:mod:`~lip_ros.lip.segmentation.segmenter` is the segmenter itself; it uses
:mod:`~lip_ros.lip.segmentation.scene` (ground plane, per-pixel background),
:mod:`~lip_ros.lip.segmentation.clusters` (clustering on the range image) and
:mod:`~lip_ros.lip.segmentation.tracking` (tracks and their association).
"""

from lip_ros.lip.segmentation.segmenter import *  # noqa: F403  (its public API is this package's)
from lip_ros.lip.segmentation.segmenter import __all__  # noqa: F401
