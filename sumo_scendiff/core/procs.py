"""Worker processes that do not outlive their parent.

A pool's parent killed by SIGTERM or SIGKILL cannot shut its pool down; its spawn workers would go on
recording or simulating for nobody. ``die_with_parent`` (a pool initializer) asks Linux to SIGKILL the
worker when the parent dies (``PR_SET_PDEATHSIG``); elsewhere it does nothing.
"""
from __future__ import annotations

import os


def die_with_parent(parent: int) -> None:
    """Pool initializer: this process is killed as soon as process ``parent`` exits."""
    try:
        import ctypes
        import signal
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:   # the parent died before the line above took effect
        os._exit(1)
