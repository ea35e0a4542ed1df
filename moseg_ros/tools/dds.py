"""Loopback-only DDS settings for every process the tools and tests start.

Fast DDS's defaults announce discovery on every network interface and lose most large best-effort images
between processes; the project's profile (config/fastdds_loopback.xml) keeps all traffic on shared memory
and 127.0.0.1. Each tool run and each test uses a ROS domain of its own so parallel runs never meet.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

PROFILE_NAME = "fastdds_loopback.xml"


def loopback_profile() -> Path:
    """Path of the loopback Fast DDS profile: the installed share/ copy, else the source checkout's."""
    candidates = [
        Path(sys.prefix) / "share" / "moseg_ros" / "config" / PROFILE_NAME,
        Path(__file__).resolve().parents[2] / "config" / PROFILE_NAME,
    ]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"{PROFILE_NAME} not found in {[str(c) for c in candidates]}")


def loopback_env(domain_id: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """Environment for a ROS process on ``domain_id`` that talks over loopback only.

    Args:
        domain_id: ROS domain (0..101 keeps clear of the ephemeral port range).
        base: environment to extend (default: this process's).
    """
    if not 0 <= domain_id <= 101:
        raise ValueError(f"ROS domain id {domain_id} must be within 0..101")
    env = dict(os.environ if base is None else base)
    profile = str(loopback_profile())
    env.update({
        "FASTRTPS_DEFAULT_PROFILES_FILE": profile,
        "FASTDDS_DEFAULT_PROFILES_FILE": profile,
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "ROS_DOMAIN_ID": str(domain_id),
        "OPENBLAS_NUM_THREADS": env.get("OPENBLAS_NUM_THREADS", "1"),
    })
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def use_loopback(domain_id: int) -> None:
    """Apply :func:`loopback_env` to this process; call before rclpy.init()."""
    os.environ.update(loopback_env(domain_id))
