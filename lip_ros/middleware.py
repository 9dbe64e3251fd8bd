"""Process settings shared by the package's executables for large point clouds: the Fast DDS profile, and
the C heap's reuse of message buffers.

Under Fast DDS's defaults a 12.6 MB Ouster cloud sent best effort between
processes does not arrive: its ~200 fragments do not fit the default 512 kB
shared-memory segment. ``params/fastdds_lip.xml`` adds a shared-memory transport
with a large segment and a deep port queue. Every executable calls
:func:`use_lip_dds_profile` before ``rclpy.init``. A profile the user chose
(``FASTRTPS_DEFAULT_PROFILES_FILE`` set) is left alone; an empty value opts out
(it is removed, as Fast DDS would log a parse error for it, and Fast DDS's
defaults apply). The profile does not touch discovery: ``ROS_AUTOMATIC_DISCOVERY_RANGE``
and ``ROS_DOMAIN_ID`` keep their meaning.

A process that ends without closing its participants (killed, or crashed) leaves
its shared-memory segments in ``/dev/shm`` (``fastrtps_*``, 128 MB each with this
profile), and Fast DDS does not reclaim them: :func:`remove_stale_shm` does
(the test session calls it at its end; ``make clean-shm`` too).

A 2048-column cloud is 12.6 MB, and taking one from DDS into Python allocates
it three times over (Fast DDS's copy, rcl's serialized message, Python's
bytes). Under glibc's default malloc options those blocks are either mapped
afresh or given back to the kernel once freed (the heap's free top beyond
twice the largest block freed), so every cloud faulted its ~9000 pages in
again: ``benchmarks/floor_node.py``, a pass-through, took 27-29 % of a core
at 2048 columns and 10 Hz, a third of it (``perf``) the kernel zeroing pages
and more faulting them in; 6-7 % with the blocks kept. The executables call
:func:`keep_message_buffers` first, so those blocks come from the heap and
stay there for the next message (docs/reliability.md "A floor that paid for
page faults").
"""

from __future__ import annotations

import ctypes
import fcntl
import os
import time
from collections.abc import Mapping, MutableMapping
from pathlib import Path

from lip_ros.resources import params_path

__all__ = ["MESSAGE_BLOCK_BYTES", "KEPT_FREE_BYTES", "PROFILE_ENV", "PROFILE_FILE", "keep_message_buffers",
           "use_lip_dds_profile", "remove_stale_shm"]

PROFILE_FILE = "fastdds_lip.xml"
PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"  # Fast DDS 2.x (ROS 2 Jazzy)
_USER_CHOICE_ENVS = (PROFILE_ENV, "FASTDDS_DEFAULT_PROFILES_FILE")  # the latter: Fast DDS 3 spelling

#: Blocks smaller than this come from malloc's heap, not a mapping of their own (``M_MMAP_THRESHOLD``; the largest
#: value older glibc versions accept on 64 bits; a 2048-column cloud is 12.6 MB).
MESSAGE_BLOCK_BYTES = 32 << 20
#: Free memory at the top of the main heap kept for the next messages rather than given back
#: (``M_TRIM_THRESHOLD``): a few clouds' copies at once. A thread's arena grows in heaps of at most 64 MB, and
#: glibc unmaps one that empties whatever this says: about five copies of a 2048-column cloud kept there.
KEPT_FREE_BYTES = 128 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's malloc.h
#: glibc's malloc options a user may set in the environment (``MALLOC_<NAME>_``) or in ``GLIBC_TUNABLES``
#: (``glibc.malloc.<name>``): any of them set, the user's choice is left alone.
_MALLOC_OPTIONS = ("trim_threshold", "mmap_threshold", "top_pad", "mmap_max")


def keep_message_buffers(environ: Mapping[str, str] | None = None) -> bool:
    """Let glibc's malloc reuse freed message-sized blocks (:data:`MESSAGE_BLOCK_BYTES`) instead of mapping and
    faulting them in again for every large message; whether it was set (False: not glibc, or the user set malloc's
    trim or mmap threshold, top pad or mmap maximum in the environment, as ``MALLOC_<NAME>_`` or in
    ``GLIBC_TUNABLES``). Up to :data:`KEPT_FREE_BYTES` of freed memory stays with the
    process. Call once, early (it applies to blocks allocated and freed afterwards)."""
    env = os.environ if environ is None else environ
    tunables = {t.split("=", 1)[0].strip() for t in env.get("GLIBC_TUNABLES", "").split(":")}
    if any(f"MALLOC_{o.upper()}_" in env or f"glibc.malloc.{o}" in tunables for o in _MALLOC_OPTIONS):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # no mallopt (macOS: its malloc has options of its own); musl's returns 0
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    mapped = mallopt(_M_MMAP_THRESHOLD, MESSAGE_BLOCK_BYTES)
    trimmed = mallopt(_M_TRIM_THRESHOLD, KEPT_FREE_BYTES)
    return bool(mapped and trimmed)


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


def remove_stale_shm(shm: Path = Path("/dev/shm"), min_age_s: float = 10.0) -> list[Path]:
    """Remove the Fast DDS shared-memory files that no live process holds: each ``fastrtps_<name>`` (a segment,
    or a port with its ``sem.fastrtps_<name>_mutex``) whose lock file ``fastrtps_<name>_el`` is locked by no
    one (Fast DDS holds it while the segment is in use) and older than ``min_age_s`` (not one being set up now).
    The files removed."""
    removed = []
    for lock in sorted(shm.glob("fastrtps_*_el")):
        try:
            if time.time() - lock.stat().st_mtime < min_age_s:
                continue
            fd = os.open(lock, os.O_RDWR)
        except OSError:  # gone meanwhile, or not ours to open
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # held: in use
            os.close(fd)
            continue
        try:
            name = lock.name.removesuffix("_el")
            for file in (shm / name, shm / f"sem.{name}_mutex", lock):
                try:
                    file.unlink()
                    removed.append(file)
                except FileNotFoundError:
                    pass
        finally:
            os.close(fd)
    return removed
