"""DDS settings shared by the package's executables: the Fast DDS profile for large point clouds.

Under Fast DDS's defaults a 12.6 MB Ouster cloud sent best effort between
processes does not arrive: its ~200 fragments do not fit the default 512 kB
shared-memory segment. ``params/fastdds_lip.xml`` adds a shared-memory transport
with a large segment and a deep port queue. Every executable calls
:func:`use_lip_dds_profile` before ``rclpy.init``. A profile the user chose
(``FASTRTPS_DEFAULT_PROFILES_FILE`` set) is left alone; an empty value opts out
(it is removed, as Fast DDS would log a parse error for it, and Fast DDS's
defaults apply). The profile does not touch discovery: ``ROS_AUTOMATIC_DISCOVERY_RANGE``
and ``ROS_DOMAIN_ID`` keep their meaning.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

from lip_ros.resources import params_path

__all__ = ["PROFILE_ENV", "PROFILE_FILE", "use_lip_dds_profile"]

PROFILE_FILE = "fastdds_lip.xml"
PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"  # Fast DDS 2.x (ROS 2 Jazzy)
_USER_CHOICE_ENVS = (PROFILE_ENV, "FASTDDS_DEFAULT_PROFILES_FILE")  # the latter: Fast DDS 3 spelling


def use_lip_dds_profile(environ: MutableMapping[str, str] | None = None) -> Path | None:
    """Point Fast DDS at the shipped profile unless the user chose otherwise; the profile set (None: user's choice).

    Call before ``rclpy.init``: Fast DDS reads the variable when the process's first participant is created.
    """
    env = os.environ if environ is None else environ
    if env.get(PROFILE_ENV) == "":
        del env[PROFILE_ENV]
        return None
    if any(name in env for name in _USER_CHOICE_ENVS):
        return None
    profile = params_path(PROFILE_FILE)
    env[PROFILE_ENV] = str(profile)
    return profile
