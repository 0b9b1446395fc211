"""CPU threads that share the machine fairly and keep scenes reproducible.

torch's intra-op pool splits every operator across its threads and waits for the slowest. Beside other
busy processes one of those threads is often descheduled, and a generation made of many small operators
waits for it at every operator: two threads on a busy two-core machine ran 9-11x slower than alone, a
fair share being 3x, spinning or sleeping alike (docs/benchmarks.md, "Threads"). One thread does not
wait for a partner, is about as fast as two on the small batches of a scene generation, and gives the
same floating-point sums whatever the machine's core count or load (two threads moved a box by 0.8 mm
against one): so the generating entry points (run, fill, sweep workers) use
:data:`GENERATION_THREADS`, and parallelism comes from worker processes. Training and evaluation keep
every core. Every entry point calls :func:`share_cpu` before torch is imported; idle OpenMP threads then
sleep (``OMP_WAIT_POLICY=PASSIVE``) instead of burning the time slice a neighbour needs. A user's own
``OMP_NUM_THREADS`` / ``OMP_WAIT_POLICY`` is kept.
"""
from __future__ import annotations

import os

GENERATION_THREADS = 1


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def share_cpu(threads: int | None = None, default: int | None = None) -> int:
    """Set OpenMP's wait policy (before torch is imported) and torch's thread count; returns it.

    ``threads`` wins, then the user's ``OMP_NUM_THREADS``, then ``default``, then every core."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    n = threads or int(os.environ.get("OMP_NUM_THREADS") or 0) or default or available_cores()
    import torch
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n
