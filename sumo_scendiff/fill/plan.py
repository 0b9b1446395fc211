"""The fill of a whole network: every tile generated, colour by colour, around its neighbours.

    result = fill_network(net, gen, tiles, seed=0)          # default: the model's prior
    result.scenes[k]              # tile k's kept agents (its window's frame), what the Seeder seeds
    result.accepted.rows          # every kept vehicle, world frame

Tile k starts from the noise of seed (seed, k) alone (``generate``'s ``noise_seeds``) and the batches
are fixed (colour, then index), so a seed gives one fill whatever else changes around it. The global
token of a tile is the share of its window its pins do not describe (:func:`~.tiles.known_share`),
times the user's ``p_mask`` (1: the model's prior).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .tiles import Accepted, Tile, colours, keep_core, known_share, pins_for, scene_rows

MIN_P_MASK = 0.05    # a global token of 0 asks for the pins alone: keep the model adding the core's traffic


@dataclass
class TileRecord:
    tile: Tile
    pins: int = 0
    p_mask: float = 1.0
    target: float | None = None       # veh/km asked for (density condition), None: prior
    generated: int = 0                # agents the model drew in the whole window
    kept: int = 0                     # ... of them in the tile's own core, overlapping nothing
    pin_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # into accepted


@dataclass
class FillResult:
    tiles: list[Tile]
    records: list[TileRecord]
    scenes: list                      # per tile: its kept agents (Scene in its window's frame)
    accepted: Accepted
    order: list[int]                  # tile indices in generation (and seeding) order


def tile_seed(seed: int, index: int) -> int:
    """The noise seed of tile ``index``: a function of the fill's seed and the tile alone."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def fill_network(net, gen, tiles: list[Tile], seed: int = 0, p_mask: float = 1.0,
                 targets: list[float | None] | None = None, use_density: bool = False,
                 area: tuple | None = None, progress: bool = False,
                 signals: dict[str, str] | None = None) -> FillResult:
    """Generate every tile; ``targets`` per tile (veh/km), given to the model with ``use_density``;
    ``signals``: the traffic lights' states at the fill's time (``sim.lights.initial_light_states``)."""
    from tqdm import tqdm
    accepted = Accepted()
    records = [TileRecord(t, target=None if targets is None else targets[t.index]) for t in tiles]
    scenes: list = [None] * len(tiles)
    owned: list[tuple] = []
    order: list[int] = []
    bar = tqdm(total=len(tiles), desc="tiles", unit=" tile", disable=not progress)
    for batch in colours(tiles):
        tokens, pm = [], []
        for t in batch:
            pins, idx = pins_for(t, accepted)
            rec = records[t.index]
            rec.pins, rec.pin_ids = len(pins), idx
            rec.p_mask = round(max(p_mask * (1.0 - known_share(net, t, owned)), MIN_P_MASK), 4)
            tokens.append(pins)
            pm.append(rec.p_mask)
        density = [records[t.index].target for t in batch] if use_density else None
        out = []
        step = gen.config.batch_size    # one model call at a time, so the bar moves per call
        for s in range(0, len(batch), step):
            part = batch[s:s + step]
            out += gen.generate(net, [t.window for t in part], tokens=tokens[s:s + step], p_mask=pm[s:s + step],
                                noise_seeds=[tile_seed(seed, t.index) for t in part],
                                density=None if density is None else density[s:s + step], signals=signals)
            bar.update(len(part))
        # the batch's tiles do not overlap: each is checked against the earlier colours only, then
        # added, in index order
        for t, scene in zip(batch, out):
            keep = keep_core(t, scene, accepted, area)
            sub = scene.select(keep)
            records[t.index].generated, records[t.index].kept = len(scene), len(sub)
            scenes[t.index] = sub
            order.append(t.index)
        for t in batch:
            accepted.add(scene_rows(scenes[t.index]), t.index)
        owned += [t.core for t in batch]
    bar.close()
    return FillResult(tiles, records, scenes, accepted, order)


__all__ = ["FillResult", "TileRecord", "fill_network", "tile_seed"]
