"""Traffic-light states of a running simulation, as the generator's map channels take them.

    states = light_states(sim, net.lights_in(window))   # {tls id: "GGrr..."} now
    states = initial_light_states(cfg)                   # the programs' states at cfg.begin

The generation conditions on the lights a scene will meet: with a host simulation its current states;
where the generator decides the start (``fill``), the states SUMO's programs have at ``--begin``,
read from SUMO itself so that actuated programs, offsets and a user's tlLogic additional files count.
"""
from __future__ import annotations

from dataclasses import replace

from .sumo import SimConfig, close, start


def light_states(sim, ids=None) -> dict[str, str]:
    """``{tls id: state}`` of the lights ``ids`` (default: all) in the running simulation ``sim``."""
    tl = sim.trafficlight
    known = set(tl.getIDList())
    return {i: tl.getRedYellowGreenState(i) for i in (sorted(known) if ids is None else ids) if i in known}


def initial_light_states(cfg: SimConfig) -> dict[str, str]:
    """The states of every light at ``cfg.begin``: SUMO started on the network and its additional
    files alone (no demand), read, closed."""
    sim = start(replace(cfg, routes=(), gui=False, traci=False))
    try:
        return light_states(sim)
    finally:
        close(sim)
