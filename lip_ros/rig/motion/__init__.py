"""Procedural full-body motion of one performer, the rig's stand-in for motion capture.

:mod:`~lip_ros.rig.motion.performer` builds a whole capture's motion from the
others: :mod:`~lip_ros.rig.motion.primitives` (smooth curves and oscillators),
:mod:`~lip_ros.rig.motion.posture` (posture channels, foot plans, leg IK),
:mod:`~lip_ros.rig.motion.clips` (what a clip is, in-place choreography),
:mod:`~lip_ros.rig.motion.gait` (walking and running) and
:mod:`~lip_ros.rig.motion.acts` (squats, jumps, arms, martial arts, dance).
"""

from lip_ros.rig.motion.performer import *  # noqa: F403  (its public API is this package's)
from lip_ros.rig.motion.performer import __all__  # noqa: F401
