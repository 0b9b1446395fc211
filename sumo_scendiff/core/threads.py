"""CPU threads that share the machine fairly.

OpenMP's worker threads (torch's intra-op pool) spin-wait between parallel regions by default. Beside
other busy processes a spinning thread burns the time slice its partner needs, and a generation that
takes a fraction of a second on an idle machine takes many times longer than its fair share
(docs/benchmarks.md, "Threads"). Every entry point calls :func:`share_cpu` before torch is imported:
idle threads then sleep (``OMP_WAIT_POLICY=PASSIVE``), and torch uses at most the cores this process
may run on. A user's own ``OMP_WAIT_POLICY`` / ``OMP_NUM_THREADS`` is kept.
"""
from __future__ import annotations

import os


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def share_cpu(threads: int | None = None) -> int:
    """Set OpenMP's wait policy (before torch is imported) and torch's thread count; returns it."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    n = threads or int(os.environ.get("OMP_NUM_THREADS") or 0) or available_cores()
    import torch
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n
