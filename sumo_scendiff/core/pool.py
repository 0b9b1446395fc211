"""Workers that build their state once and then run tasks: in this process, on a local process pool,
or as Ray actors, behind one interface.

    with LocalPool(Worker, args, workers=2) as pool:         # each process: Worker(*args, **kwargs)
        for i, result in pool.map_unordered(tasks):           # worker.run(*tasks[i]), as they finish
            ...

A worker is any picklable class whose instances have ``run(*task)`` (and optionally ``close()``);
building one may be expensive (a model, a network), so each process or actor builds it once.
Local workers die with their parent (``core.procs``), so a caller killed with SIGKILL leaves no
orphan. Results come back with their task's index, in the order they finish: a caller that must
not depend on the worker count puts them back in task order itself.
"""
from __future__ import annotations

import os
import signal

from .procs import die_with_parent

RAY_HINT = "pip install 'sumo-scendiff[ray]'"


TASK_TRIES = 3      # deaths of the worker running a task before the task is given up (an error)


class EngineError(RuntimeError):
    """The engine cannot run (Ray missing, cluster unreachable, a worker that cannot start): one line."""


def import_ray(flag: str):
    """The ``ray`` module, or an :class:`EngineError` naming the ``flag`` that asked for it."""
    try:
        import ray
    except ImportError:
        raise EngineError(f"{flag} needs Ray: {RAY_HINT}") from None
    return ray


class InProcess:
    """The same interface around one worker in this process (one worker: no pool to pay for)."""

    def __init__(self, worker):
        self.worker = worker

    def map_unordered(self, tasks):
        for i, task in enumerate(tasks):
            yield i, self.worker.run(*task)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


_WORKER = None
_START_ERROR: str | None = None


def _init(factory, args, kwargs, parent: int) -> None:
    global _WORKER, _START_ERROR
    die_with_parent(parent)
    # Ctrl-C reaches the whole process group: the parent answers it (and ends the pool), not each worker
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        _WORKER = factory(*args, **kwargs)
    except Exception as e:   # noqa: BLE001 -- an initializer that raises makes the pool respawn it forever
        _START_ERROR = f"{type(e).__name__}: {e}".splitlines()[0]


def _run(item):
    if _START_ERROR is not None:
        raise EngineError(f"a worker process could not start ({_START_ERROR})")
    i, task = item
    return i, _WORKER.run(*task)


class LocalPool:
    """``workers`` spawned processes, each building ``factory(*args, **kwargs)`` once. A worker that
    dies in the middle (SIGKILL, out of memory) takes the pool with it: a new pool runs the tasks
    that were running again; a task running at :data:`TASK_TRIES` deaths is an EngineError naming it."""

    def __init__(self, factory, args=(), kwargs=None, workers: int = 2):
        self.workers = workers
        self._initargs = (factory, tuple(args), dict(kwargs or {}), os.getpid())
        self.pool = self._start()

    def _start(self):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor
        # spawn, no fork: torch's and SUMO's state does not survive one
        return ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"), initializer=_init,
                                   initargs=self._initargs)

    def map_unordered(self, tasks, name=None):
        """(index, result) of each task as they finish; ``name(task)``: how an error names a task."""
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool
        tasks, deaths = list(tasks), {}
        todo, running = list(range(len(tasks)))[::-1], {}
        while todo or running:
            while todo and len(running) < self.workers:   # no more queued than run: a death costs those only
                i = todo.pop()
                running[self.pool.submit(_run, (i, tasks[i]))] = i
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            broken = [f for f in done if isinstance(f.exception(), BrokenProcessPool)]
            for f in done:
                if f not in broken:
                    del running[f]
                    yield f.result()
            if not broken:
                continue
            lost = sorted(running.values())    # every task the dead pool held
            running.clear()
            self.pool.shutdown(wait=True, cancel_futures=True)
            for i in lost:
                deaths[i] = deaths.get(i, 0) + 1
                if deaths[i] >= TASK_TRIES:
                    what = name(tasks[i]) if name else f"task {i + 1} of {len(tasks)}"
                    raise EngineError(f"{what}: its worker process died {TASK_TRIES} times while running it "
                                      f"(killed, or out of memory)")
            todo += lost[::-1]
            self.pool = self._start()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is not None:    # nobody wants the results (an error, Ctrl-C): the workers end now
            for proc in (getattr(self.pool, "_processes", None) or {}).values():
                proc.terminate()
        self.pool.shutdown(wait=True, cancel_futures=True)
        return False


class RayPool:
    """``workers`` Ray actors (one CPU each) on the cluster at ``address`` (None or ``"local"``: a local
    instance of ``workers`` CPUs), each building ``factory(*args, **kwargs)`` once. ``flag``: what
    the user asked Ray with, named when Ray is missing."""

    def __init__(self, factory, args=(), kwargs=None, workers: int = 1, address: str | None = None,
                 flag: str = "--ray-address"):
        ray = self.ray = import_ray(flag)
        address = None if address == "local" else address
        self.started = not ray.is_initialized()
        if self.started:
            try:
                kw = {"address": address} if address else {"num_cpus": workers}
                ray.init(include_dashboard=False, logging_level="ERROR", log_to_driver=False, **kw)
            except Exception as e:  # ConnectionError, ...: a cluster that is not there
                raise EngineError(f"Ray: cannot start or reach {address or 'a local instance'} "
                                  f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
        actor = ray.remote(num_cpus=1)(factory)
        self._new = lambda: actor.remote(*args, **(kwargs or {}))
        self.actors = [self._new() for _ in range(workers)]
        self.closes = hasattr(factory, "close")

    def map_unordered(self, tasks, name=None):
        """(index, result) of each task as they finish. An actor that dies in the middle of a task
        is replaced and the task run again; one whose actor dies :data:`TASK_TRIES` times is an
        EngineError naming it (``name(task)``)."""
        from ray.exceptions import RayActorError
        ray, tasks = self.ray, list(tasks)
        idle, running, deaths, todo = list(self.actors), {}, {}, list(range(len(tasks)))[::-1]
        while todo or running:
            while idle and todo:
                a, i = idle.pop(), todo.pop()
                running[a.run.remote(*tasks[i])] = (i, a)
            [ref], _ = ray.wait(list(running), num_returns=1)
            i, a = running.pop(ref)
            try:
                result = ray.get(ref)
            except RayActorError:
                deaths[i] = deaths.get(i, 0) + 1
                if deaths[i] >= TASK_TRIES:
                    what = name(tasks[i]) if name else f"task {i + 1} of {len(tasks)}"
                    raise EngineError(f"{what}: the Ray actor running it died {TASK_TRIES} times") from None
                self.actors[self.actors.index(a)] = a = self._new()
                todo.append(i)
                idle.append(a)
                continue
            idle.append(a)
            yield i, result

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        ray = self.ray
        try:
            if exc_type is None and self.closes:
                ray.get([a.close.remote() for a in self.actors])
        finally:
            if self.started:
                ray.shutdown()
            else:   # someone else's Ray: leave it, without our actors
                for a in self.actors:
                    ray.kill(a)
        return False


__all__ = ["EngineError", "InProcess", "LocalPool", "RayPool", "import_ray"]
