"""What this machine can hold: the memory a process may still allocate, for checks made before
a setting or a received file sizes an allocation (:mod:`hypa.core.trust`, the test bench's settings)."""

from __future__ import annotations

import os
from pathlib import Path


def available_memory() -> int | None:
    """Bytes this process may still allocate: the kernel's ``MemAvailable`` (else the physical
    memory), at most what a control group's limit leaves; ``None`` where the machine does not say."""
    found = [_meminfo_available() or _physical_memory(), *map(_cgroup_room, CGROUP_FILES)]
    found = [f for f in found if f is not None and f > 0]
    return min(found) if found else None


CGROUP_FILES = (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),  # v2
                ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"))  # v1


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024  # kB
    except (OSError, ValueError, IndexError):
        return None
    return None


def _physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _cgroup_room(files: tuple[str, str]) -> int | None:
    """A control group's memory limit less its usage; ``None`` without one (or ``max``: no limit)."""
    try:
        return int(Path(files[0]).read_text().strip()) - int(Path(files[1]).read_text().strip())
    except (OSError, ValueError):
        return None


__all__ = ["available_memory"]
