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
    """``workers`` spawned processes, each building ``factory(*args, **kwargs)`` once."""

    def __init__(self, factory, args=(), kwargs=None, workers: int = 2):
        import multiprocessing as mp
        ctx = mp.get_context("spawn")   # no fork: torch's and SUMO's state does not survive one
        self.pool = ctx.Pool(workers, initializer=_init, initargs=(factory, tuple(args), dict(kwargs or {}),
                                                                  os.getpid()))

    def map_unordered(self, tasks):
        yield from self.pool.imap_unordered(_run, enumerate(tasks))

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is None:
            # workers that exit on their own release what they registered with the parent's resource
            # tracker (tqdm's lock): terminated ones leave "leaked semaphore" warnings on stderr
            self.pool.close()
        else:
            self.pool.terminate()   # nobody wants the results
        self.pool.join()
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
        self.actors = [actor.remote(*args, **(kwargs or {})) for _ in range(workers)]
        self.closes = hasattr(factory, "close")

    def map_unordered(self, tasks):
        ray, tasks = self.ray, list(tasks)
        idle, running, nxt = list(self.actors), {}, 0
        while nxt < len(tasks) or running:
            while idle and nxt < len(tasks):
                a = idle.pop()
                running[a.run.remote(*tasks[nxt])] = (nxt, a)
                nxt += 1
            [ref], _ = ray.wait(list(running), num_returns=1)
            i, a = running.pop(ref)
            idle.append(a)
            yield i, ray.get(ref)

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
