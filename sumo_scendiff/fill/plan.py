"""The fill of a whole network: every tile generated, colour by colour, around its neighbours.

    result = fill_network(net, gen, tiles, seed=0)          # default: the model's prior
    with tile_engine(net, gen, workers=2) as engine:        # the same fill on two worker processes
        result = fill_network(net, gen, tiles, seed=0, engine=engine)
    result.scenes[k]              # tile k's kept agents (its window's frame), what the Seeder seeds
    result.accepted.rows          # every kept vehicle, world frame

Tile k starts from the noise of seed (seed, k) alone (``generate``'s ``noise_seeds``), the batches
are fixed (colour, then index), and so are the model calls they are cut into (:func:`tasks_of`), so a
seed gives one fill whatever else changes around it, the number of workers included. The global
token of a tile is the share of its window its pins do not describe (:func:`~.tiles.known_share`),
times the user's ``p_mask`` (1: the model's prior). With ``demand`` (the demand's vehicles en route,
:func:`~.en_route.place_en_route`) each tile is also given those whose centre is in its core, as
tokens of pose and size: the model draws them there, with speeds and paths of its own, and each
kept agent drawn for one says which (``scene.meta["demand"]``, its index into ``demand``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .tiles import Accepted, Tile, colours, in_area, keep_core, known_share, pins_for, scene_rows

TILES_PER_TASK = 16  # tiles per model call at most: a worker's share of a colour, and the bar's step
TASKS_PER_COLOUR = 4  # a colour's model calls at least (where it has the tiles): two workers share them
MIN_P_MASK = 0.05    # a global token of 0 asks for the pins alone: keep the model adding the core's traffic


@dataclass
class TileRecord:
    tile: Tile
    pins: int = 0
    p_mask: float = 1.0
    target: float | None = None       # veh/km asked for (density condition), None: prior
    generated: int = 0                # agents the model drew in the whole window
    kept: int = 0                     # ... of them in the tile's own core, overlapping nothing
    demand: list[int] = field(default_factory=list)   # the demand's vehicles given as tokens (indices)
    pin_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # into accepted


@dataclass
class FillResult:
    tiles: list[Tile]
    records: list[TileRecord]
    scenes: list                      # per tile: its kept agents (Scene in its window's frame)
    accepted: Accepted
    order: list[int]                  # tile indices in generation (and seeding) order
    demand: list | None = None        # the placed demand vehicles the tiles were given (en_route.Placed)


def tile_seed(seed: int, index: int) -> int:
    """The noise seed of tile ``index``: a function of the fill's seed and the tile alone."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def tasks_of(batch: list[Tile]) -> list[list[Tile]]:
    """A colour's tiles cut into model calls: :data:`TASKS_PER_COLOUR` groups (so that workers share
    the load) or more, at most ``TILES_PER_TASK`` tiles each (a larger batch costs the model less per
    tile). The cut depends on the colour alone, never on the worker count: a model call's float sums
    may depend on what else is in its batch (tokens are padded to the longest set, guidance runs for
    the batch), and the same seed must give the same fill on one worker or many."""
    size = max(1, min(TILES_PER_TASK, math.ceil(len(batch) / TASKS_PER_COLOUR)))
    return [batch[s:s + size] for s in range(0, len(batch), size)]


def whole_counts(targets: list[float | None], kms: list[float]) -> list[float | None]:
    """Per tile density targets (veh per km of car lane) made whole: the expected vehicles,
    target x km, apportioned to integer counts by largest remainder (ties to the lower tile index) so
    that they add up to the rounded total, returned as densities whose round(D x km) is that count.
    Rounding each tile alone loses the whole network's traffic where tiles expect less than half a
    vehicle (545 ingolstadt21 tiles expecting 315 vehicles kept 276)."""
    idx = [k for k, (t, km) in enumerate(zip(targets, kms)) if t is not None and km > 0]
    want = np.array([targets[k] * kms[k] for k in idx], np.float64)
    if not len(want):
        return list(targets)
    n = np.floor(want).astype(np.int64)
    short = int(round(want.sum())) - int(n.sum())
    order = sorted(range(len(idx)), key=lambda j: (-(want[j] - n[j]), j))
    for j in order[:max(short, 0)]:
        n[j] += 1
    out = list(targets)
    for j, k in enumerate(idx):
        out[k] = float(n[j]) / kms[k]
    return out


def fill_network(net, gen, tiles: list[Tile], seed: int = 0, p_mask: float = 1.0,
                 targets: list[float | None] | None = None, use_density: bool = False,
                 area: tuple | None = None, progress: bool = False,
                 signals: dict[str, str] | None = None, engine=None, demand: list | None = None) -> FillResult:
    """Generate every tile; ``targets`` per tile (veh/km), given to the model with ``use_density``;
    ``signals``: the traffic lights' states at the fill's time (``sim.lights.initial_light_states``);
    ``engine``: where the model calls run (:func:`~.workers.tile_engine`; default: ``gen`` here);
    ``demand``: vehicles (:class:`~.en_route.Placed`) each tile is given as tokens in its core."""
    from tqdm import tqdm

    from .workers import tile_engine
    engine = engine or tile_engine(net, gen)   # ``gen`` in this process: nothing to close
    accepted = Accepted()
    records = [TileRecord(t, target=None if targets is None else targets[t.index]) for t in tiles]
    for k, t in enumerate(demand_tiles(tiles, demand or [], area)):
        if t is not None:
            records[t].demand.append(k)
    scenes: list = [None] * len(tiles)
    owned: list[tuple] = []
    order: list[int] = []
    bar = tqdm(total=len(tiles), desc="tiles", unit=" tile", disable=not progress)
    for batch in colours(tiles):
        pins = {}
        for t in batch:
            tokens, idx = pins_for(t, accepted)
            rec = records[t.index]
            rec.pins, rec.pin_ids = len(tokens), idx
            tokens = tokens + [demand_token(t, demand[k]) for k in rec.demand]
            rec.p_mask = round(max(p_mask * (1.0 - known_share(net, t, owned)), MIN_P_MASK), 4)
            pins[t.index] = tokens
        groups = tasks_of(batch)
        tasks = [([t.window for t in g], [pins[t.index] for t in g], [records[t.index].p_mask for t in g],
                  [tile_seed(seed, t.index) for t in g],
                  [records[t.index].target for t in g] if use_density else None, signals,
                  [t.core for t in g]) for g in groups]
        out: dict[int, object] = {}
        for k, part in engine.map_unordered(tasks):
            out.update({t.index: scene for t, scene in zip(groups[k], part)})
            bar.update(len(part))
        # the batch's tiles do not overlap: each is checked against the earlier colours only, then
        # added, in index order (whichever worker finished first)
        for t in batch:
            if demand is not None:
                _name_demand(out[t.index], records[t.index])
            keep = keep_core(t, out[t.index], accepted, area)
            sub = out[t.index].select(keep)
            records[t.index].generated, records[t.index].kept = len(out[t.index]), len(sub)
            scenes[t.index] = sub
            order.append(t.index)
        for t in batch:
            accepted.add(scene_rows(scenes[t.index]), t.index)
        owned += [t.core for t in batch]
    bar.close()
    return FillResult(tiles, records, scenes, accepted, order, demand)


def demand_tiles(tiles: list[Tile], placed: list, area: tuple | None = None) -> list[int | None]:
    """Per placed vehicle, the index of the tile whose core holds its centre (None: no tile's, or
    outside ``area``)."""
    out: list[int | None] = [None] * len(placed)
    if not placed:
        return out
    xy = np.array([[p.x, p.y] for p in placed])
    inside = in_area(xy, area)
    for t in tiles:
        for k in np.flatnonzero(t.in_core(xy) & inside):
            if out[k] is None:
                out[k] = t.index
    return out


def demand_token(tile: Tile, p) -> dict:
    """A placed demand vehicle as a token of ``tile``'s window: pose and size (its speed and path
    are the model's)."""
    w = tile.window
    xy = w.world_to_scene(np.array([[p.x, p.y]]))[0]
    return {"x": float(xy[0]), "y": float(xy[1]), "heading": float(w.yaw_to_scene(p.heading)),
            "length": float(p.length), "width": float(p.width)}


def _name_demand(scene, rec: TileRecord) -> None:
    """``scene.meta["demand"]``: per agent the demand vehicle it was drawn for (index), else None.
    The generator says which token each agent delivers; the tile's tokens are its pins, then its
    demand vehicles."""
    delivers = scene.meta.get("delivers") or [None] * len(scene)
    scene.meta["demand"] = [rec.demand[d - rec.pins] if d is not None and rec.pins <= d < rec.pins + len(rec.demand)
                            else None for d in delivers]


__all__ = ["FillResult", "TileRecord", "demand_tiles", "demand_token", "fill_network", "tasks_of", "tile_seed"]
