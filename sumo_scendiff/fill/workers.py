"""Where a fill's tiles are generated: in this process, on local worker processes, or on Ray.

    with tile_engine(net, gen, workers=2) as engine:          # each worker loads net and model once
        result = fill_network(net, gen, tiles, engine=engine)

Only the model calls leave the parent: pins, p_mask, keeping the core and the order in which tiles are
accepted stay in :func:`~.plan.fill_network`. A task is a group of tiles of one colour with
everything the model needs (windows, pinned tokens, global tokens, noise seeds, densities, lights), so
a worker holds no state between tasks, and what it returns depends on the task alone.
"""
from __future__ import annotations

import os

from ..core.pool import InProcess, LocalPool, RayPool


class TileWorker:
    """Generates tasks of tiles; builds its network and model once (or is given the parent's)."""

    def __init__(self, net_path: str | None = None, checkpoint: str | None = None, config=None,
                 net=None, generator=None):
        if generator is None:
            from ..core.threads import GENERATION_THREADS, share_cpu
            # the parent's rule (user's OMP_NUM_THREADS, else one thread): the same float sums there and here
            share_cpu(default=GENERATION_THREADS)
            from ..generation.generator import ScenarioGenerator
            generator = ScenarioGenerator.load(checkpoint, config) if config is not None \
                else ScenarioGenerator.load(checkpoint)
        if net is None:
            from ..map.network import Network
            net = Network.load(net_path)
        self.net, self.gen = net, generator

    def run(self, windows, tokens, p_mask, noise_seeds, density=None, signals=None, cores=None) -> list:
        # a tile's density is kept as a count in its core: the overlap belongs to its neighbours
        return self.gen.generate(self.net, windows, tokens=tokens, p_mask=p_mask, noise_seeds=noise_seeds,
                                 density=density, signals=signals, count_areas=cores)


def default_workers() -> int:
    """Worker processes when none are asked for: one per core this process may use, each generating
    on one thread (core/threads.py: why one)."""
    from ..core.threads import available_cores
    return max(1, available_cores())


def tile_engine(net, gen, workers: int = 1, ray_address: str | None = None, checkpoint: str | None = None):
    """The engine (a context manager, ``map_unordered(tasks)``) for ``workers`` workers; with
    ``ray_address`` Ray actors there (paths made absolute: an actor's directory is not ours). The
    parent's ``gen`` and ``net`` serve a single local worker; others load ``checkpoint``."""
    if ray_address is None and workers <= 1:
        return InProcess(TileWorker(net=net, generator=gen))
    args = (os.path.abspath(net.path), checkpoint and os.path.abspath(checkpoint), gen.config)
    if ray_address is not None:
        return RayPool(TileWorker, args, workers=workers, address=ray_address, flag="--ray-address")
    return LocalPool(TileWorker, args, workers=workers)


__all__ = ["TileWorker", "default_workers", "tile_engine"]
