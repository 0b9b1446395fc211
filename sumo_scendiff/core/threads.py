"""CPU threads that share the machine fairly.

torch's intra-op pool splits every operator across its threads and waits for the slowest. Beside other
busy processes one of those threads is often descheduled, and a generation made of many small operators
waits for it at every operator: two threads on a busy two-core machine ran many times slower than their
fair share, spinning or sleeping (docs/benchmarks.md, "Threads"). So every entry point calls
:func:`share_cpu` before torch is imported: torch gets as many threads as there are cores free *now*
(at least one), and idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE``) instead of burning the time
slice a neighbour needs. A user's own ``OMP_NUM_THREADS`` / ``OMP_WAIT_POLICY`` is kept.
"""
from __future__ import annotations

import os
import time


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def _cpu_times() -> tuple[float, float] | None:
    """(busy, total) jiffies of the whole machine from /proc/stat, or None where there is none."""
    try:
        with open("/proc/stat") as f:
            fields = [float(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0.0)   # idle + iowait
    total = sum(fields[:8])                                      # guest time is already in user
    return total - idle, total


def busy_cores(interval: float = 0.15) -> float:
    """Cores' worth of CPU the machine spent over the next ``interval`` seconds (0 where unknown).

    Sampled while this process sleeps, so it is what the other processes use.
    """
    a = _cpu_times()
    if a is None:
        return 0.0
    time.sleep(interval)
    b = _cpu_times()
    if b is None or b[1] <= a[1]:
        return 0.0
    return (b[0] - a[0]) / (b[1] - a[1]) * (os.cpu_count() or 1)


def free_cores() -> int:
    """Cores this process may run on that nobody else is using now; at least one."""
    n = available_cores()
    return max(1, min(n, int(n - busy_cores() + 0.5)))


def share_cpu(threads: int | None = None) -> int:
    """Set OpenMP's wait policy (before torch is imported) and torch's thread count; returns it.

    ``threads`` wins, then ``OMP_NUM_THREADS``, then the cores free at this moment.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    n = threads or int(os.environ.get("OMP_NUM_THREADS") or 0) or free_cores()
    import torch
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n
