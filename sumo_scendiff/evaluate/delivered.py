"""Generated scenes with the sizes SUMO gets: each agent given the scenario's vType the seeder gives it.

    fleet = scenario_fleet(net, routes)       # the demand's vTypes and their mix (None: no demand)
    scenes = with_fleet(scenes, fleet, net, seed)

With a demand, ``run`` and the fill seed each generated agent as one of the scenario's own vTypes
(:mod:`sumo_scendiff.sim.fleet`: a fleet drawn from the demand's mix, each type to the box it fits
best, a longer type only where it keeps clear of the boxes ahead and behind), so the vehicles in SUMO
have the scenario's lengths and widths, not the model's. The JSD set measures the sizes a user's
simulation holds on these copies, beside the model's own (raw) sizes.
"""
from __future__ import annotations

import copy
from typing import Sequence

import numpy as np

from ..core.scene import Scene
from ..map.network import Network


def scenario_fleet(net: Network, routes: str | None):
    """The vTypes of ``routes`` as SUMO reads them and the mix its departures make; None without a
    demand or when SUMO refuses it (the seeder keeps the model's sizes then, too)."""
    if routes is None:
        return None
    from ..sim.fleet import Fleet
    from ..sim.sumo import SimConfig, SimError, close, start
    try:
        sim = start(SimConfig(net.path, routes=(routes,)))
    except SimError:
        return None
    try:
        fleet = Fleet.read(sim, files=[routes])
        for name in {*fleet.share, *(m for d in fleet.dists.values() for m in d if m in fleet.names)}:
            fleet.get(name)   # read now: SUMO is closed when the fleet is used
    finally:
        close(sim)
    return fleet if fleet.active else None


def with_fleet(scenes: Sequence[Scene], fleet, net: Network, seed: int) -> list[Scene]:
    """Copies of ``scenes`` whose agents have the sizes and classes of the vTypes ``fleet`` assigns."""
    if fleet is None:
        return list(scenes)
    from ..sim.seeding import Seeder
    out = []
    for i, scene in enumerate(scenes):
        s = copy.deepcopy(scene)
        lead, gap = Seeder.leaders(s.boxes)   # the room a longer type has, as the seeder measures it
        fleet.assign(s, np.zeros((0, 5), np.float32), lead, gap, net, None, np.random.default_rng([seed, 11, i]))
        out.append(s)
    return out
