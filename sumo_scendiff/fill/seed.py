"""The filled network in one SUMO, and the files that start stock SUMO from it (the inflow that
keeps a fill without demand going: fill/inflow.py).

    sim, reports = seed_fill(result, net, SimConfig(net=path, begin=t), seed=0)
    sim.simulation.saveState("state.xml.gz")
    write_start_routes("start.rou.xml", sim, ids, net, begin=t)
    write_sumocfg("scenario.sumocfg", options, "state.xml.gz", routes=[...])   # sim.export

Every tile's kept agents go through the one :class:`~sumo_scendiff.sim.seeding.Seeder` in the fill's
order (its routes: the generated trajectory, then on to a destination, sim/routes.py), with the
vehicles of earlier tiles around them as the leaders they may be behind; then one simulation step
puts them all where they were generated, and every tile's report is verified and settled against
the leaders SUMO itself sees (across tile borders too).
"""
from __future__ import annotations

import os
import re
from collections import Counter
from contextlib import contextmanager

import numpy as np

from ..sim.export import loaded_files, write_routes
from ..sim.fleet import Fleet
from ..sim.seeding import Seeder
from ..sim.stops import add_stops, drop_passed
from .tiles import scene_rows
from ..sim.sumo import start
# the inflow's names, as the tests import them from here (they lived here before fill/inflow.py)
from .inflow import (  # noqa: F401
    MAX_DEPART_DELAY_S,
    SUPPLY,
    fringe_sources,
    inflow_sample,
    probe_speed,
    route_metres,
    trip_seconds,
    write_inflow,
)

# the earlier tiles' vehicles a tile's seeding sees: within this many window sizes of its centre
# (its corners are 0.71 away; a long vehicle's box reaches in from a little beyond)
REACH = 0.9


# a refusal SUMO names one vehicle in ("busStop 's' for vehicle 'v' ...", "Vehicle 'v' ...")
_NAMED = re.compile(r"[Vv]ehicle '([^']+)'")
# vehicles taken out one by one, each named by SUMO's refusal to load the folder, before the refusal
# is taken for the whole input's (then it is the user's to see, one line)
MAX_REFUSED_AT_LOAD = 20






def seed_fill(result, net, cfg, seed: int = 0, quiet: bool = True, progress: bool = False,
              demand: list | None = None, routes=(), model_fleet: bool = False, sim=None):
    """Start SUMO (``cfg``; ``sim``: started on it already), seed every tile, step once, verify and
    settle. Returns (sim, reports per tile index). ``demand``: the placed demand vehicles the tiles were given (plan.py): an agent
    drawn for one drives the rest of its route, with its vType where ``cfg`` loads it. With a
    demand (``routes``) every seeded vehicle is one of its vTypes (sim/fleet.py), unless
    ``model_fleet`` (then the model's sizes on SUMO's default vType). What SUMO
    says meanwhile (with ``quiet`` False: a warning for each destination its router finds no way
    to) is shown after, each kind once with its count (core.sumo_log)."""
    from ..core.sumo_log import caught_stderr, echo
    with caught_stderr() as said:
        try:
            out = _seed_all(result, net, cfg, seed, quiet, progress, demand, routes, model_fleet, sim)
        finally:
            echo(said())
    return out


def _seed_all(result, net, cfg, seed, quiet, progress, demand, routes, model_fleet=False, sim=None):
    from tqdm import tqdm
    sim = sim or start(cfg, quiet=quiet)
    seeder = Seeder(sim, net, prefix="fill", seed=seed)
    if model_fleet:        # a fleet without a mix: no drawn agent is given a scenario's vType (--model-fleet)
        seeder.fleet = Fleet(sim, {})
    elif demand or routes:   # the mix: the vehicles en route at --begin (as run's are those present), else the route files'
        seeder.fleet = Fleet.read(sim, mix=Counter(p.vehicle.type or "DEFAULT_VEHTYPE" for p in demand or ()),
                                  files=[*routes, *cfg.additional])
    reports: dict[int, object] = {}
    # the vehicles seeded so far, world rows (x, y, heading, length, width, speed) where the seeder put
    # them: a tile's pins are its neighbours as drawn, but the seeder moves some (a nose over the stop
    # line pulled back, a car waiting inside a junction on red to its stop line) and refuses others
    seeded, stopping, spaces = np.zeros((0, 6)), [], []
    for k in tqdm(result.order, desc="seeding", unit=" tile", disable=not progress):
        scene = result.scenes[k]
        if scene is None or not len(scene):
            continue
        w = scene.window
        # the earlier tiles' vehicles around this window: leaders the Seeder fits gaps and speeds to,
        # places a vehicle it moves may not take
        pins = seeded[np.hypot(seeded[:, 0] - w.cx, seeded[:, 1] - w.cy) <= REACH * w.size]
        others = np.zeros((len(pins), 5))
        if len(pins):
            others[:, :2] = w.world_to_scene(pins[:, :2])
            others[:, 2] = w.yaw_to_scene(pins[:, 2])
            others[:, 3:] = pins[:, 3:5]
        seeder.prefix, seeder.count = f"fill{k}.", 0
        which = scene.meta.get("demand")
        mine = [None if d is None else demand[d].vehicle for d in which] if demand and which else None
        _stand_at_stops(scene, mine)
        reports[k] = seeder.seed(scene, others=(others, pins[:, 5] if len(pins) else np.zeros(0)),
                                 routes=[v and v.edges for v in mine] if mine else None,
                                 types=[v and v.type for v in mine] if mine else None)
        stopping += _give_stops(sim, reports[k], mine)
        spaces += [(scene, a, reports[k], demand[d].vehicle) for a, d in enumerate(which or ())
                   if d is not None and demand[d].space and a in reports[k].ids]
        seeded = np.vstack([seeded, scene_rows(scene)[sorted(reports[k].ids)]])
    _to_space_entry(sim, net, spaces)
    sim.simulationStep()
    for rep in reports.values():
        seeder.verify(rep)
    for rep in reports.values():
        seeder.settle(rep)
    for vid in stopping:     # verify and settle move some: a stop they moved past is passed
        drop_passed(sim, vid)
    return sim, reports


def _stand_at_stops(scene, mine) -> None:
    """The agents whose demand vehicle stands at its stop at the fill's time (``mine``, per agent)
    seeded standing, whatever speed the model drew: SUMO lets a vehicle make a stop only if it can
    brake for it, and one moving at the stop's end would pass it."""
    for a, v in enumerate(mine or ()):
        if v is not None and v.stopped is not None:
            scene.speed[a] = 0.0


def _to_space_entry(sim, net, spaces) -> None:
    """The seeded vehicles parked at T in a parking area's ``<space>``s (``spaces``: scene, agent, its
    report, its demand vehicle) moved to the area's end, where SUMO enters every space from
    (``MSParkingArea::addLotEntry`` without ``--parking.maneuver``): they stand there together after
    the seeding step and all park in the next, each in a space of its own, off the lane before SUMO
    looks for collisions. Seeded one behind the other (a seeding puts no two vehicles at one place),
    each would drive up from standing and park seconds after the one before it, where SUMO's own run
    has them all parked. The agent's pose is the moved one (fill.json ``to_space_entry_m``)."""
    from ..core.geometry import center_to_front, yaw_to_sumo_angle
    for scene, a, rep, v in spaces:
        vid, lane = rep.ids[a], net.lane_index.get(v.stop_lane)
        if lane is None:
            continue
        length = float(scene.boxes[a, 3])
        xy, yaw = net.lane_pose(lane, v.stop_at - 0.5 * length)
        fx, fy = center_to_front(xy[0], xy[1], yaw, length)
        edge, _, index = v.stop_lane.rpartition("_")
        try:    # a vehicle SUMO has still to insert takes where to stand from moveToXY (its front)
            sim.vehicle.moveToXY(vid, edge, int(index), float(fx), float(fy), keepRoute=1)
        except Exception:   # libsumo's TraCIException: that lane is not on its route where it stands
            continue
        w = scene.window
        box = np.array([*w.world_to_scene(np.asarray(xy)[None])[0], w.yaw_to_scene(yaw)])
        scene.meta.setdefault("to_space_entry", {})[a] = round(float(np.hypot(*(box[:2] - scene.boxes[a, :2]))), 3)
        scene.boxes[a, :3] = box
        scene.traj[a, :, 0], scene.traj[a, :, 1], scene.traj[a, :, 2] = box[0], box[1], box[2]
        rep.targets[a] = (float(fx), float(fy), float(yaw_to_sumo_angle(yaw)))


def _give_stops(sim, rep, mine) -> list[str]:
    """The stops each seeded vehicle's demand vehicle (``mine``, per agent) still has to make, but
    those behind where it stands on its lane (sim.stops); returns the vehicles given any. One
    standing at its stop begins it in the step after the seeding one: the rest of its duration is
    counted from then."""
    out, late = [], 2.0 * sim.simulation.getDeltaT()
    for a, v in enumerate(mine or ()):
        vid = rep.ids.get(a)
        if v is None or not v.stops or vid is None:
            continue
        lane = rep.lanes.get(a)      # (normal lane, front position); none inside a junction
        at = (lane[0].rpartition("_")[0], lane[1]) if lane else None
        if add_stops(sim, vid, v.stops_left(late), at=at):
            out.append(vid)
    return out


def write_start_routes(path: str, sim, ids, net, begin: float, vtype_files=()) -> dict[str, bool]:
    """start.rou.xml: every seeded vehicle departing at ``begin`` where it stands (its vType, its
    remaining route, departLane/departPos/departPosLat/departSpeed); vehicles inside a junction
    start at the end of the lane leading into it (``exact`` False). ``vtype_files``: the scenario's
    files defining the vTypes the seeded vehicles copy."""
    files = list(vtype_files) + list(loaded_files(sim))
    exact = write_routes(path, sim, ids, net, vtype_files=files)
    _unscaled(path, _scale(sim), files)
    if begin:
        # export.write_routes departs everyone at 0 (a scene folder starts at 0); here at --begin
        with open(path) as f:
            text = f.read()
        with open(path, "w") as f:
            f.write(re.sub(r' depart="0" ', f' depart="{begin:g}" ', text))
    return exact


# SUMO's default vTypes by the vClass they are (a vehicle of the demand without a type drives one)
DEFAULT_VTYPES = {"DEFAULT_VEHTYPE": "passenger", "DEFAULT_BIKETYPE": "bicycle", "DEFAULT_TAXITYPE": "taxi",
                  "DEFAULT_RAILTYPE": "rail"}


def _scale(sim) -> float:
    """The scenario's ``--scale`` (SUMO's demand factor) the running SUMO has."""
    try:
        return float(sim.simulation.getOption("scale"))
    except Exception:   # a SUMO without getOption: no scaling known
        return 1.0


def _unscaled(path: str, scale: float, files) -> None:
    """The portable start's vehicles each loaded once where the scenario scales its demand: SUMO scales
    every vehicle it reads by ``--scale`` times its vType's ``scale``, and the start's vehicles are those
    on the road, copies included (a second copy, stacked on the first, or "Another vehicle with the id
    'pas27.1' exists"). Each vType they drive gets ``scale`` 1/``scale``: their own as written, one of
    the scenario's (``files``) or SUMO's defaults as a copy ``start.TYPE`` (the demand keeps its own)."""
    if abs(scale - 1.0) < 1e-9:
        return
    import copy
    import xml.etree.ElementTree as ET

    from ..sim.export import declared_vtypes
    tree = ET.parse(path)
    root = tree.getroot()
    own = {el.get("id"): el for el in root if el.tag == "vType"}
    theirs = declared_vtypes(files)
    copies = {}
    for veh in (el for el in root if el.tag == "vehicle"):
        tid = veh.get("type") or "DEFAULT_VEHTYPE"
        if tid in own and tid not in theirs and not tid.startswith("DEFAULT_"):
            own[tid].set("scale", f"{1.0 / scale:.9g}")
            continue
        if tid not in copies:
            el = copy.deepcopy(theirs[tid]) if tid in theirs else \
                ET.Element("vType", vClass=DEFAULT_VTYPES.get(tid, "passenger"))
            el.attrib.pop("probability", None)      # a member of a vTypeDistribution stands alone here
            el.set("id", f"start.{tid}")
            el.set("scale", f"{1.0 / scale:.9g}")
            el.tail = "\n    "
            copies[tid] = el
        veh.set("type", f"start.{tid}")
    for k, el in enumerate(copies.values()):
        root.insert(k, el)
    tree.write(path, encoding="UTF-8", xml_declaration=True)


def load_each(load, vehicles, remove) -> dict[str, str]:
    """Call ``load()`` (a SUMO start on the folder's files) until SUMO takes them: each time it
    refuses naming one of ``vehicles``, ``remove(vid)`` takes that vehicle out and it is tried again
    (at most :data:`MAX_REFUSED_AT_LOAD` times); returns vehicle id -> SUMO's reason. One vehicle
    does not sink the folder; a refusal that names none of them is the input's and is raised."""
    from ..sim.sumo import SimError
    refused: dict[str, str] = {}
    while True:
        try:
            load()
            return refused
        except SimError as e:
            found = _NAMED.search(str(e))
            vid = found.group(1) if found else None
            if vid not in vehicles or vid in refused or len(refused) >= MAX_REFUSED_AT_LOAD:
                raise
            refused[vid] = str(e).removeprefix("SUMO refused to start: ")
            remove(vid)


def remove_vehicle(vid: str, routes_path: str | None = None, state_path: str | None = None,
                   state_vid: str | None = None) -> None:
    """Take vehicle ``vid`` out of a portable start's route file (its vehicle and its route) and out
    of a saved state (its vehicle, a parked one's transfer back to its lane, and its place in its
    lane's list of vehicles); ``state_vid``: its id in the state where that is another."""
    import gzip
    import xml.etree.ElementTree as ET
    for path, vid in ((routes_path, vid), (state_path, state_vid or vid)):
        if not path:
            continue
        opener = gzip.open if path.endswith(".gz") else open
        with opener(path, "rb") as f:
            tree = ET.parse(f)
        root = tree.getroot()
        for el in list(root):
            if el.tag in ("vehicle", "vehicleTransfer") and el.get("id") == vid \
                    or el.tag == "route" and el.get("id") == f"{vid}_replay":
                root.remove(el)
        for lst in root.iter("vehicles"):      # a state's <lane><vehicles value="a b"/></lane>
            ids = lst.get("value", "").split()
            if vid in ids:
                lst.set("value", " ".join(v for v in ids if v != vid))
        with opener(path, "wb") as f:
            tree.write(f, encoding="UTF-8", xml_declaration=True)


def admit_start(folder: str, poses: dict, ends: dict, state_ids: dict[str, str] | None = None,
                said: set[str] | None = None) -> tuple[int, dict[str, str]]:
    """The folder's two starts, made to load in SUMO: the portable start's stops SUMO would refuse
    pruned (sim.stops.prune_file_stops; ``ends``: the stopping places), its departures fitted to the
    box centres (``poses``: vehicle id -> x, y; sim.export.fit_departures), and the state loaded
    and stepped once; a vehicle SUMO still refuses at either is taken out of both
    (:func:`load_each`; ``state_ids``: the portable start's id -> the state's, where they differ).
    What SUMO says loading them is shown once, each kind not in ``said`` (:func:`said_once`).
    Returns (departures fitted, vehicle id -> SUMO's reason per one taken out)."""
    from ..sim.export import fit_departures
    from ..sim.stops import prune_file_stops
    from ..sim.sumo import close, start_config
    routes, state = os.path.join(folder, "start.rou.xml"), os.path.join(folder, "state.xml.gz")
    prune_file_stops(routes, ends)
    fitted, said = [0], set() if said is None else said

    def fit():
        fitted[0] = fit_departures(os.path.join(folder, "start.sumocfg"), routes, poses)

    def step_state():
        sim = start_config(os.path.join(folder, "scenario.sumocfg"))
        try:
            sim.simulationStep()
        finally:
            close(sim)

    named = {vid: (state_ids or {}).get(vid, vid) for vid in poses}   # as the state names them
    portable = {v: vid for vid, v in named.items()}

    def remove(vid):
        remove_vehicle(vid, routes, state, named[vid])
    refused = load_each(lambda: _caught(fit, said), set(poses), remove)
    prune_file_stops(routes, ends)   # a departure the fit moved past its stop's end
    by_state = load_each(lambda: _caught(step_state, said), {named[v] for v in poses if v not in refused},
                         lambda v: remove(portable[v]))
    refused.update({portable[v]: why for v, why in by_state.items()})
    return fitted[0], refused


def _caught(run, said: set[str] | None = None) -> None:
    """``run()`` (SUMO started on the folder, its first step) with SUMO's console caught: what
    fails at the first step (a route it cannot drive: libsumo's FatalTraCIError says nothing) is a
    SimError with SUMO's first error, as a refusal to start is. What SUMO says meanwhile is shown
    after, once (:func:`said_once`)."""
    from ..core.sumo_log import first_error
    from ..sim.sumo import SimError
    with said_once(set() if said is None else said) as text:
        try:
            run()
        except SimError:
            raise
        except Exception as e:   # libsumo's FatalTraCIError / TraCIException
            raise SimError(f"SUMO refused to start: {first_error(text()) or str(e) or type(e).__name__}") from None


@contextmanager
def said_once(said: set[str]):
    """What SUMO says while the block runs (on its stderr, and what sim.sumo echoes of its loading),
    shown after it, but the kinds of message in ``said`` (core.sumo_log.shape: the shapes shown
    already, added to): the fill loads the user's files and then the folder's copies of them several
    times, and each load says the same, a flawed include naming its copy. Yields a function
    returning what SUMO wrote on its stderr so far; a block that raises shows nothing (its error says it)."""
    import contextlib
    import io

    from ..core.sumo_log import caught_stderr, echo, shape
    with caught_stderr() as text, contextlib.redirect_stderr(io.StringIO()) as echoed:
        yield text
        lines = list(dict.fromkeys((echoed.getvalue() + text()).splitlines()))   # a line each start says: once
    echo("\n".join(ln for ln in lines if shape(ln) not in said))
    said.update(shape(ln) for ln in lines)


def refuse_at_load(agents: list[dict], refused: dict[str, str]) -> None:
    """fill.json's agents whose vehicle SUMO refused when loading the folder (:func:`admit_start`):
    refused, with SUMO's reason, and no vehicle."""
    for a in agents:
        why = refused.get(a["vehicle"]) if a["vehicle"] is not None else None
        if why is not None:
            a.update(status="refused", reason=f"SUMO refused it when loading the folder: {why}", vehicle=None)


__all__ = ["MAX_REFUSED_AT_LOAD", "REACH", "admit_start", "load_each", "refuse_at_load", "remove_vehicle", "seed_fill",
           "write_start_routes"]
