"""The seeding benchmark's SUMO side (benchmarks/seeding.py starts it as ``seeding.py --worker IN OUT``,
a fresh interpreter per net): the net's demand warmed up to T and saved, then per window and method a
fresh SUMO at that state, the window's agents (SUMO's own, or the window emptied and a scene seeded),
one step and the rollout, tallied.

No model and no torch here: the scenes come generated in the pickle, and what else this process
holds is kept fixed, because SUMO's steps after a ``loadState`` depend on where its objects lie in
memory (seeding.py's docstring has the measurements).
"""
from __future__ import annotations

import os
import re
import time
from collections import Counter

from seeding_tables import METHODS


def _reason(msg: str) -> str:
    """A refusal message with vehicle / route / type ids blanked, so equal causes count together."""
    return re.sub(r"'[^']*'", "'…'", msg)[:120]


def sim_config(path: str, dem: tuple, o):
    """The SUMO configuration of a net's warm-up and rollouts (``dem`` from seeding.demand)."""
    from sumo_scendiff.sim.sumo import SimConfig
    routes, begin, extra, _ = dem
    return SimConfig(net=path, routes=(routes,), step_length=o.step_length, seed=o.seed, begin=begin,
                     extra=tuple(["--ignore-route-errors", "true"] + extra))


def _warm_state(cfg, until: float, base: str) -> tuple[float, int]:
    """The demand run to ``until`` and its state saved to ``base``: (wall s, vehicles on the road)."""
    from sumo_scendiff.sim.sumo import close, start
    sim = start(cfg)
    try:
        t = time.perf_counter()
        sim.simulationStep(until)
        t_warm = time.perf_counter() - t
        on_road = len(sim.vehicle.getIDList())
        sim.simulation.saveState(base)
    finally:
        close(sim)
    return t_warm, on_road


def _cosim(sim, net, o):
    """The co-simulation seeding a window, its seeder's rules as the options say."""
    from sumo_scendiff.sim.cosim import CoSimulation
    cosim = CoSimulation(sim, net, None, seed=o.seed)
    cosim.seeder.resolve_junctions = getattr(o, "junction_rule", True)
    cosim.seeder.junction_leaders_on = getattr(o, "junction_leaders", True)
    cosim.seeder.red_to_stop_line = getattr(o, "red_stop_line", True)
    if not getattr(o, "width_cap", True):
        cosim.seeder.width_cap = None
    return cosim


def _tracer(sim, net, o, name: str, k: int):
    """The event tracer of SUMO's and the model's rollouts with ``--events`` (None: not traced)."""
    if not getattr(o, "events", False) or name == "Lane-uniform":
        return None
    from sumo_scendiff.sim.events import EventTracer
    return EventTracer(sim, net, [], label={"net": net.name, "window": k, "method": name})


def _traced(tracer) -> list:
    """A rollout's events and its host-only collisions, as the events pickle holds them."""
    return tracer.events + [{"kind": "host-host", "t": x[0], "lane": x[3], "ids": x[1:3], **tracer.label}
                            for x in tracer.others]


def _own(sim, ex, o, tracer, r: dict, events: list) -> None:
    """(a) SUMO's own traffic in the window: one step, then the rollout of its vehicles."""
    from sumo_scendiff.sim.rollout import rollout
    sim.simulationStep()
    if tracer is not None:
        tracer.agents = set(ex.token_ids())
    r["stats"].append(rollout(sim, ex.token_ids(), o.rollout, tracer=tracer))
    if tracer is not None:
        events += _traced(tracer)


def _tally(r: dict, scene, seeding) -> None:
    """A seeded window's placement added to its method's counts."""
    import numpy as np
    rep = seeding.report
    r["generated"] += len(scene)
    r["dropped"] += seeding.dropped
    r["refused"].update(_reason(m) for m in rep.refused.values())
    r["absent"] += sum(1 for e in rep.misplaced.values() if not np.isfinite(e))
    r["off_pose"] += sum(1 for e in rep.misplaced.values() if np.isfinite(e))
    r["placed"] += rep.placed
    r["slowed"] += len(rep.slowed)
    r["fitted"] += len(rep.gap_fitted)
    r["narrowed"] += len(rep.narrowed)
    r["pulled_back"] += len(rep.pulled_back)
    r["to_stop_line"] += len(rep.to_stop_line)
    r["junction"] += len(getattr(rep, "conflicts", ()))


def _seeded(sim, cosim, ex, scene, o, tracer, r: dict, events: list) -> None:
    """(b), (c): the window emptied, ``scene`` seeded around the vehicles outside it, one step,
    then the rollout of the agents seeded."""
    import numpy as np

    from sumo_scendiff.sim.cosim import Existing
    from sumo_scendiff.sim.rollout import rollout
    for vid in ex.token_ids():
        sim.vehicle.remove(vid)
    out = ~ex.inside
    around = Existing([i for i, keep in zip(ex.ids, out) if keep], ex.boxes[out],
                      ex.speed[out], np.zeros(int(out.sum()), bool))
    seeding = cosim.place(scene, [], [], around, seed=o.seed, p_mask=1.0)
    sim.simulationStep()
    cosim.verify(seeding)
    _tally(r, scene, seeding)
    if tracer is not None:
        from sumo_scendiff.sim.events import seed_info
        tracer.agents = set(seeding.agent_ids)
        tracer.seeded = seed_info(sim, seeding.report, seeding.scene)
        for d in tracer.seeded.values():
            if d.get("internal"):
                d["own_link"] = tracer.link_of(d["lane"])
    r["stats"].append(rollout(sim, seeding.agent_ids, o.rollout, tracer=tracer))
    if tracer is not None:
        events += _traced(tracer)
        events.append({"kind": "seeded", "seeded": tracer.seeded, **tracer.label})


def _window(cfg, base: str, net, w, k: int, name: str, scene, o, r: dict, events: list) -> None:
    """One method in window ``w`` (``scene`` None: SUMO's own) in a fresh SUMO at the base state, as
    run's Session does: each starts from the same state and the same random streams, whatever ran
    before it."""
    from sumo_scendiff.sim.sumo import close, start
    sim = start(cfg)
    try:
        sim.simulation.loadState(base)
        cosim = _cosim(sim, net, o)
        ex = cosim.existing(w)
        tracer = _tracer(sim, net, o, name, k)
        if scene is None:
            _own(sim, ex, o, tracer, r, events)
        else:
            _seeded(sim, cosim, ex, scene, o, tracer, r, events)
    finally:
        close(sim)


def simulate(path: str, windows: list, scenes: list, o, dem: tuple, work: str) -> dict:
    """The SUMO part of one network (runs in the child process); ``dem`` from seeding.demand,
    ``work`` the directory for the saved state."""
    # every module the rollouts use, imported before SUMO starts (the memory layout, see above)
    import numpy as np  # noqa: F401

    from sumo_scendiff.evaluate.baselines import LaneUniform
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.cosim import CoSimulation, Existing  # noqa: F401
    from sumo_scendiff.sim.rollout import rollout  # noqa: F401
    from sumo_scendiff.sim.sumo import close, start  # noqa: F401

    net = Network.load(path)
    lane = LaneUniform(net, seed=o.seed)
    lu_scenes = [lane.generate(w, index=i) for i, w in enumerate(windows)]
    begin, label = dem[1], dem[3]
    cfg = sim_config(path, dem, o)
    base = os.path.join(work, "state.xml")
    t_warm, on_road = _warm_state(cfg, begin + o.warmup, base)
    res = {m: {"stats": [], "generated": 0, "dropped": 0, "refused": Counter(), "absent": 0,
               "off_pose": 0, "placed": 0, "slowed": 0, "fitted": 0, "junction": 0,
               "narrowed": 0, "pulled_back": 0, "to_stop_line": 0} for m in METHODS}
    t = time.perf_counter()
    events = []
    for k, w in enumerate(windows):
        for name, scene in zip(METHODS, (None, scenes[k], lu_scenes[k])):
            _window(cfg, base, net, w, k, name, scene, o, res[name], events)
        print(k + 1, flush=True)                           # progress, for the parent's bar
    t_windows = time.perf_counter() - t
    return {"demand": label, "on_road": on_road, "methods": res, "events": events,
            "seconds": {"warmup": t_warm, "windows": t_windows}}


def worker(src: str, dst: str) -> int:
    """``--worker IN OUT``: :func:`simulate` on a pickled net's inputs (the SUMO process)."""
    import pickle
    import types
    with open(src, "rb") as f:
        job = pickle.load(f)
    r = simulate(job["path"], job["windows"], job["scenes"], types.SimpleNamespace(**job["opts"]),
                 job["demand"], job["dir"])
    with open(dst, "wb") as f:
        pickle.dump(r, f)
    return 0
