"""How many CPU cores this process may run on, for the engines that step envs on threads or processes."""

from __future__ import annotations

import os


def available_cores() -> int:
    """The CPU cores this process may run on (honours ``taskset``)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
