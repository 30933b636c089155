"""Worker processes that end with the process that started them (run workers, the synthetic
suite's generators)."""

from __future__ import annotations

import ctypes
import os
import signal
import sys


def die_with_parent(parent: int | None) -> None:
    """Linux: ask the kernel to SIGKILL this process when its parent ends, even by ``kill -9``
    (``prctl(PR_SET_PDEATHSIG)``; no library wraps it, and polling the parent cannot interrupt
    a block that is running). A parent that ended before the request: exit now. Elsewhere a
    worker outlives a killed driver until its task ends."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
    if parent is not None and os.getppid() != parent:
        os._exit(1)
