"""Running sweep tasks: in this process, on a local process pool, or on Ray.

Every engine hands whole tasks (scenarios sharing a network and sampler settings, see
:func:`tasks`) to workers that each load the model once; progress is counted in scenarios as tasks
finish. Workers of the local pool die with their parent (Linux ``PR_SET_PDEATHSIG``), so a sweep
killed with SIGKILL leaves no orphan writing into the output directory.
"""
from __future__ import annotations

import math
import os
from itertools import groupby

from ..core.procs import die_with_parent
from ..core.threads import GENERATION_THREADS
from .spec import Scenario, Spec

TASK_SIZE = 8   # scenarios per task: the model call batches them; small enough to balance workers


class EngineError(RuntimeError):
    """The engine cannot run (Ray missing, cluster unreachable): one line."""


Task = tuple[list[Scenario], frozenset]   # (scenarios generated in one batch, ids done before)


def tasks(scenarios: list[Scenario], todo: set[str] | None = None, size: int = TASK_SIZE) -> list[Task]:
    """Group the whole plan by (network, step length, sampler settings), cut it into batches of at
    most ``size`` scenarios (fewer for a small plan, so that there are about eight), and keep the
    batches with a scenario in ``todo`` (default: all). The batches depend on the plan alone, not
    on the worker count or on what a resumed sweep finished before, so every scene is generated in
    the same batch: a resumed or re-partitioned sweep writes what an uninterrupted one does."""
    key = lambda s: (s.network, s.step_length, s.steps, s.threshold, s.guidance,  # noqa: E731
                     -1.0 if s.scene_guidance is None else s.scene_guidance, s.pin_tokens,
                     s.pin_speeds, s.lane_headings, s.lane_snap)
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


_WORKER = None


def _init(spec: Spec, out: str, checkpoint: str | None, threads: int, parent: int) -> None:
    global _WORKER
    die_with_parent(parent)
    from .worker import Worker
    _WORKER = Worker(spec, out, checkpoint, threads=threads)


def _run(task: Task) -> list[str]:
    return _WORKER.run(*task)


def run_local(all_tasks, spec: Spec, out: str, workers: int, checkpoint=None, bar=None) -> None:
    if workers <= 1:
        from .worker import Worker
        w = Worker(spec, out, checkpoint)
        try:
            for t in all_tasks:
                done = w.run(*t)
                if bar is not None:
                    bar.update(len(done))
        finally:
            w.close()
        return
    import multiprocessing as mp
    ctx = mp.get_context("spawn")
    with ctx.Pool(workers, initializer=_init, initargs=(spec, out, checkpoint, _threads(workers), os.getpid())) as pool:
        for done in pool.imap_unordered(_run, all_tasks):
            if bar is not None:
                bar.update(len(done))


def run_ray(all_tasks, spec: Spec, out: str, workers: int, checkpoint=None, bar=None,
            address: str | None = None) -> None:
    try:
        import ray
        from ray.util import ActorPool
    except ImportError:
        raise EngineError("--engine ray needs Ray: pip install 'sumo-scendiff[ray]'") from None
    from .worker import Worker
    started = not ray.is_initialized()
    if started:
        try:
            kw = {"address": address} if address else {"num_cpus": workers}
            ray.init(include_dashboard=False, logging_level="ERROR", log_to_driver=False, **kw)
        except Exception as e:  # ConnectionError, ...: a cluster that is not there
            raise EngineError(f"Ray: cannot start or reach {address or 'a local instance'} "
                              f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
    try:
        actor = ray.remote(num_cpus=1)(Worker)
        actors = [actor.remote(spec, out, checkpoint, threads=1) for _ in range(workers)]
        pool = ActorPool(actors)
        for done in pool.map_unordered(lambda a, t: a.run.remote(*t), all_tasks):
            if bar is not None:
                bar.update(len(done))
        ray.get([a.close.remote() for a in actors])
    finally:
        if started:
            ray.shutdown()
