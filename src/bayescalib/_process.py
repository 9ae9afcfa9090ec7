"""Process helpers shared by the job server and the isolated solves."""

from __future__ import annotations

import os
import signal

__all__ = ["die_with_parent"]


def die_with_parent(parent: int) -> None:
    """Have the kernel SIGKILL this process when its parent ``parent`` dies (Linux
    ``PR_SET_PDEATHSIG``; elsewhere nothing happens). A job or a solve whose run was
    killed then ends with it instead of living on as an orphan that holds the
    study's job lock. If the parent is already gone, exit now."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:
        os._exit(1)
