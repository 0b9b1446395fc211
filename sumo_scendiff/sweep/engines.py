"""Running sweep tasks: on a local process pool, or on Ray.

Every engine hands whole tasks (scenarios sharing a network and sampler settings, see
:func:`tasks`) to workers that each load the model once; progress is counted in scenarios as tasks
finish. A single worker runs in a process of the pool too, not in the sweep's own: a native crash
of libsumo (SUMO 1.28 on some state loads) then kills a worker the pool replaces and runs the task
again, as with more workers, not the sweep. Workers of the local pool die with their parent (Linux
``PR_SET_PDEATHSIG``), so a sweep killed with SIGKILL leaves no orphan writing into the output
directory. The pools are ``core.pool``'s, shared with the whole-network fill.
"""
from __future__ import annotations

import math
from itertools import groupby

from ..core.pool import EngineError, LocalPool, RayPool
from ..core.threads import GENERATION_THREADS
from .spec import Scenario, Spec

TASK_SIZE = 8   # scenarios per task: the model call batches them; small enough to balance workers


Task = tuple[list[Scenario], frozenset]   # (scenarios generated in one batch, ids done before)


def tasks(scenarios: list[Scenario], todo: set[str] | None = None, size: int = TASK_SIZE) -> list[Task]:
    """Group the whole plan by (network, step length, sampler settings), cut it into batches of at
    most ``size`` scenarios (fewer for a small plan, so that there are about eight), and keep the
    batches with a scenario in ``todo`` (default: all). The batches depend on the plan alone, not
    on the worker count or on what a resumed sweep finished before, so every scene is generated in
    the same batch: a resumed or re-partitioned sweep writes what an uninterrupted one does."""
    key = lambda s: (s.network, s.step_length, s.steps, s.threshold, s.guidance,  # noqa: E731
                     -1.0 if s.scene_guidance is None else s.scene_guidance, s.pin_tokens,
                     s.pin_speeds, s.lane_headings, s.lane_snap, s.generation.count_on_edges)
    size = max(1, min(size, math.ceil(len(scenarios) / 8)))
    todo = {s.id for s in scenarios} if todo is None else set(todo)
    out = []
    for _, group in groupby(sorted(scenarios, key=lambda s: (key(s), s.id)), key=key):
        group = list(group)
        for i in range(0, len(group), size):
            batch = group[i:i + size]
            if any(s.id in todo for s in batch):
                out.append((batch, frozenset(s.id for s in batch if s.id not in todo)))
    return out


def _threads(workers: int) -> int:
    """Torch threads per worker: one, whatever the worker count (core/threads.py), so that the same
    seed gives the same scenes with 1 or N workers; parallelism is the workers'."""
    return GENERATION_THREADS


def _names(task: Task) -> str:
    """A task as an error names it: its scenarios."""
    return "scenarios " + ", ".join(s.id for s in task[0])


def _drain(pool, all_tasks, bar) -> None:
    """Run every task on ``pool``, counting each finished task's scenarios on ``bar``."""
    for _, done in pool.map_unordered(all_tasks, name=_names):
        if bar is not None:
            bar.update(len(done))


def run_local(all_tasks, spec: Spec, out: str, workers: int, checkpoint=None, bar=None) -> None:
    from .worker import Worker
    with LocalPool(Worker, (spec, out, checkpoint), {"threads": _threads(workers)}, max(1, workers)) as pool:
        _drain(pool, all_tasks, bar)


def run_ray(all_tasks, spec: Spec, out: str, workers: int, checkpoint=None, bar=None,
            address: str | None = None) -> None:
    from .worker import Worker
    with RayPool(Worker, (spec, out, checkpoint), {"threads": 1}, workers, address,
                 flag="--engine ray") as pool:
        _drain(pool, all_tasks, bar)


__all__ = ["EngineError", "TASK_SIZE", "run_local", "run_ray", "tasks"]
