"""The filled network in one SUMO, and the files that start stock SUMO from it.

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
import subprocess
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..sim.export import loaded_files, write_routes
from ..sim.fleet import Fleet
from ..sim.seeding import Seeder
from ..sim.stops import add_stops, drop_passed
from .tiles import scene_rows
from ..sim.sumo import start

TYPICAL_SPEED_FACTOR = 0.7  # a trip time's floor: its routes at this share of the speed limits
INFLOW_SECONDS = 3600.0     # how long the continuing inflow runs after the start
SAMPLE_TRIPS = 200          # random trips: their mean route gives the trip time; the probe's replacements
# The probe (probe_speed) drives the filled network on, keeping its number of vehicles, for
# SETTLE_SECONDS unmeasured, then measures its mean speed for PROBE_SECONDS. Both are one cycle of
# netconvert's default signal programs (90 s; grid4x4_2lane_tls's too): the speed swings with the
# phases (on that grid between 2 and 7 m/s within a cycle), so a window of whole cycles sees every
# approach's green and red once. The first cycle is not measured: in it the generated start turns into
# SUMO's own queues (and on a closed grid nine in ten seeded vehicles reach their route's end and are
# replaced), and it flows faster than the held network: on that grid a fill of 457 vehicles (30 veh/km)
# ran at 4.2 m/s in the first cycle, a rate that grew to gridlock (80 veh/km) within 30 min, and at
# 2.8 m/s in the second. Measuring two cycles instead of one cost time and changed little (3.38 against
# 3.46 m/s on a fill of 430 vehicles there).
SETTLE_SECONDS = 90.0
PROBE_SECONDS = 90.0
# The inflow offers SUPPLY times the rate Little's law estimates, and SUMO's --max-num-vehicles (in
# both configurations) holds the network at the filled number: vehicles beyond it wait to enter. An
# open-loop rate alone is unstable on a signalised network: a little too high and the queues grow
# to gridlock, a little too low and it drains (grid4x4 at 25 veh/km, three seeds: -24 % to +21 %
# after 30 min); with the cap an estimate up to SUPPLY times too low still holds the count.
SUPPLY = 1.5
# The supply beyond what leaves waits to enter; SUMO drops a vehicle that has waited this long
# (--max-depart-delay, in both configurations), so the waiting list stays bounded (about
# (SUPPLY - 1) x the leaving rate x this) instead of growing over the hour.
MAX_DEPART_DELAY_S = 60.0
# SUMO inserts a car from standing on a lane about every 2 s (its default car on a straight road:
# 2.05 s at 1 s steps, docs/fill.md); the inflow enters at the fringe only where the fringe's lanes
# can take its rate at FRINGE_LOAD of that (sources take unequal shares, a light stops some), else
# anywhere: a city entered by five edges cannot be held full through them
INSERT_HEADWAY_S = 2.0
FRINGE_LOAD = 0.5
# the earlier tiles' vehicles a tile's seeding sees: within this many window sizes of its centre
# (its corners are 0.71 away; a long vehicle's box reaches in from a little beyond)
REACH = 0.9


# a refusal SUMO names one vehicle in ("busStop 's' for vehicle 'v' ...", "Vehicle 'v' ...")
_NAMED = re.compile(r"[Vv]ehicle '([^']+)'")
# vehicles taken out one by one, each named by SUMO's refusal to load the folder, before the refusal
# is taken for the whole input's (then it is the user's to see, one line)
MAX_REFUSED_AT_LOAD = 20


class InflowError(RuntimeError):
    """randomTrips.py could not make the inflow (one line: its last message)."""




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
    seeded, stopping = np.zeros((0, 6)), []
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
        seeded = np.vstack([seeded, scene_rows(scene)[sorted(reports[k].ids)]])
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


def remove_vehicle(vid: str, routes_path: str | None = None, state_path: str | None = None) -> None:
    """Take vehicle ``vid`` out of a portable start's route file (its vehicle and its route) and out
    of a saved state (its vehicle, and its place in its lane's list of vehicles)."""
    import gzip
    import xml.etree.ElementTree as ET
    for path in (routes_path, state_path):
        if not path:
            continue
        opener = gzip.open if path.endswith(".gz") else open
        with opener(path, "rb") as f:
            tree = ET.parse(f)
        root = tree.getroot()
        for el in list(root):
            if el.tag == "vehicle" and el.get("id") == vid or el.tag == "route" and el.get("id") == f"{vid}_replay":
                root.remove(el)
        for lst in root.iter("vehicles"):      # a state's <lane><vehicles value="a b"/></lane>
            ids = lst.get("value", "").split()
            if vid in ids:
                lst.set("value", " ".join(v for v in ids if v != vid))
        with opener(path, "wb") as f:
            tree.write(f, encoding="UTF-8", xml_declaration=True)


def admit_start(folder: str, poses: dict, ends: dict) -> tuple[int, dict[str, str]]:
    """The folder's two starts, made to load in SUMO: the portable start's stops SUMO would refuse
    pruned (sim.stops.prune_file_stops; ``ends``: the stopping places), its departures fitted to the
    box centres (``poses``: vehicle id -> x, y; sim.export.fit_departures), and the state loaded
    and stepped once; a vehicle SUMO still refuses at either is taken out of both
    (:func:`load_each`). Returns (departures fitted, vehicle id -> SUMO's reason per one taken out)."""
    from ..sim.export import fit_departures
    from ..sim.stops import prune_file_stops
    from ..sim.sumo import close, start_config
    routes, state = os.path.join(folder, "start.rou.xml"), os.path.join(folder, "state.xml.gz")
    prune_file_stops(routes, ends)
    fitted = [0]

    def fit():
        fitted[0] = fit_departures(os.path.join(folder, "start.sumocfg"), routes, poses)

    def step_state():
        sim = start_config(os.path.join(folder, "scenario.sumocfg"))
        try:
            sim.simulationStep()
        finally:
            close(sim)

    def remove(vid):
        remove_vehicle(vid, routes, state)
    refused = load_each(lambda: _caught(fit), set(poses), remove)
    prune_file_stops(routes, ends)   # a departure the fit moved past its stop's end
    refused.update(load_each(lambda: _caught(step_state), set(poses) - set(refused), remove))
    return fitted[0], refused


def _caught(run) -> None:
    """``run()`` (SUMO started on the folder, its first step) with SUMO's console caught: what
    fails at the first step (a route it cannot drive: libsumo's FatalTraCIError says nothing) is a
    SimError with SUMO's first error, as a refusal to start is."""
    from ..core.sumo_log import caught_stderr, echo, first_error
    from ..sim.sumo import SimError
    with caught_stderr() as text:
        try:
            run()
        except SimError:
            raise
        except Exception as e:   # libsumo's FatalTraCIError / TraCIException
            raise SimError(f"SUMO refused to start: {first_error(text()) or str(e) or type(e).__name__}") from None
        said = text()
    echo(said)


def refuse_at_load(agents: list[dict], refused: dict[str, str]) -> None:
    """fill.json's agents whose vehicle SUMO refused when loading the folder (:func:`admit_start`):
    refused, with SUMO's reason, and no vehicle."""
    for a in agents:
        why = refused.get(a["vehicle"]) if a["vehicle"] is not None else None
        if why is not None:
            a.update(status="refused", reason=f"SUMO refused it when loading the folder: {why}", vehicle=None)


def fringe_sources(net) -> list[str]:
    """Car edges nothing leads onto but their own reverse: where traffic enters the network."""
    snet = net.sumo_net
    out = []
    for e in snet.getEdges(withInternal=False):
        if not e.allows("passenger"):
            continue
        # a junction's internal edges (a dead end's turnaround) are not a way in
        inc = [p for p in e.getIncoming() if p.allows("passenger") and p.getFunction() in ("", "normal")
               and not (p.getFromNode() is e.getToNode() and p.getToNode() is e.getFromNode())]
        if not inc:
            out.append(e.getID())
    return sorted(out)


def _random_trips(net_file: str, path: str, begin: float, period: float, seed: int, fringe: bool,
                  end: float | None = None) -> list[list[str]]:
    """Run randomTrips.py (validated by duarouter: every trip has a route) into ``path``; returns
    the routes it found. Its intermediate files stay in a temporary folder."""
    from ..core.files import check_whole
    from ..core.tools import sumo_home, sumo_tool
    args = [sys.executable, sumo_tool("randomTrips.py"), "-n", os.path.abspath(net_file),
            "-o", os.path.abspath(path), "-r", "routes.rou.xml", "-b", f"{begin:g}",
            "-e", f"{begin + INFLOW_SECONDS if end is None else end:g}", "-p", f"{period:.3f}", "--seed", str(seed),
            "--prefix", "inflow", "--vehicle-class", "passenger", "--edge-permission", "passenger",
            "--validate"] + (["--fringe-factor", "max"] if fringe else [])
    with tempfile.TemporaryDirectory(prefix="scendiff-inflow-") as work:
        done = subprocess.run(args, check=False, env={**os.environ, "SUMO_HOME": sumo_home()}, cwd=work,
                              capture_output=True, text=True)
        if done.returncode != 0 or not os.path.exists(path):
            msg = (done.stderr or done.stdout).strip().splitlines()
            from ..core.outputs import final_name
            raise InflowError(f"randomTrips.py failed writing into {final_name(os.path.dirname(os.path.abspath(path)))}: "
                              f"{msg[-1] if msg else done.returncode}")
        check_whole(path)
        routes = os.path.join(work, "routes.rou.xml")
        if not os.path.exists(routes):
            return []
        from sumolib.xml import parse
        return [r.edges.split() for r in parse(routes, "route")]


def trip_seconds(net, routes: list[list[str]]) -> float:
    """The mean free-flow time of the routes (at the typical share of the speed limits)."""
    snet = net.sumo_net
    times = [sum(snet.getEdge(e).getLength() / max(snet.getEdge(e).getSpeed() * TYPICAL_SPEED_FACTOR, 0.1)
                 for e in r if snet.hasEdge(e)) for r in routes]
    return float(np.mean(times)) if times else 0.0


def route_metres(net, routes: list[list[str]]) -> float:
    """The mean length of the routes, junctions (internal lanes) included: the distance a trip drives."""
    from sumolib.route import getLength
    snet = net.sumo_net
    lengths = [getLength(snet, [e for e in r if snet.hasEdge(e)]) for r in routes]
    return float(np.mean(lengths)) if lengths else 0.0


def fringe_capacity(net, sources: list[str]) -> float:
    """Vehicles per second the car lanes of ``sources`` insert at :data:`FRINGE_LOAD`."""
    snet = net.sumo_net
    lanes = sum(ln.allows("passenger") for e in sources for ln in snet.getEdge(e).getLanes())
    return FRINGE_LOAD * lanes / INSERT_HEADWAY_S


def inflow_sample(net, begin: float, seed: int, vehicles: int = 0) -> tuple[list[list[str]], bool]:
    """The routes of the first :data:`SAMPLE_TRIPS` random trips the inflow is drawn from, validated
    by duarouter ([] if randomTrips.py finds none), and whether they enter at the fringe: where the
    network has one whose lanes can insert the rate that holds ``vehicles`` (:data:`SUPPLY` times
    ``vehicles`` over the trips' free-flow time; :func:`fringe_capacity`), else anywhere
    (randomTrips.py's default: edges by length)."""
    sources = fringe_sources(net)
    with tempfile.TemporaryDirectory(prefix="scendiff-sample-") as work:
        path = os.path.join(work, "sample.rou.xml")
        if sources:
            routes = _random_trips(net.path, path, begin, INFLOW_SECONDS / SAMPLE_TRIPS, seed, True)
            trip_s = trip_seconds(net, routes)
            if routes and trip_s > 0 and vehicles * SUPPLY / trip_s <= fringe_capacity(net, sources):
                return routes, True
        return _random_trips(net.path, path, begin, INFLOW_SECONDS / SAMPLE_TRIPS, seed, False), False


@dataclass
class Probe:
    """What :func:`probe_speed` saw: ``record`` for fill.json (the speed in ``mean_speed_ms``), the
    replacements it made (``departures``: time, route), and the simulation time it ended at."""
    record: dict
    departures: list = field(default_factory=list)
    until: float = 0.0

    @property
    def speed(self) -> float | None:
        return self.record.get("mean_speed_ms")


def probe_speed(sim, routes: list[list[str]], seconds: float = PROBE_SECONDS, settle: float = SETTLE_SECONDS,
                prefix: str = "probe") -> Probe:
    """Drive the (filled) simulation ``sim`` on for ``settle`` + ``seconds`` and measure, over the last
    ``seconds``, the network's space-mean speed: the sum of every present vehicle's speed over the steps
    / the vehicle-steps, standing vehicles included (Little's law needs the real mean: stops at red and
    in queues count).

    The number of vehicles is kept: each vehicle that arrives is replaced at once by the next of
    ``routes`` (the inflow's own trips, departing as they will: speed 0 at the start of the first
    edge). Without that the probe would measure an emptying network, faster than the held one (on a
    closed grid the seeded vehicles' routes end within seconds). Those replacements are the inflow's
    first departures (:func:`write_inflow`). Changes ``sim``: call it after the state and start routes
    are written."""
    dt = float(sim.simulation.getDeltaT())
    n_settle, n_probe = int(round(settle / dt)), max(int(round(seconds / dt)), 1)
    known = set(sim.route.getIDList())
    sums = {"settle": [0.0, 0], "probe": [0.0, 0]}     # speed sum, vehicle-steps
    counts, departures = [], []
    for step in range(n_settle + n_probe):
        sim.simulationStep()
        now = float(sim.simulation.getTime())
        for _gone in sim.simulation.getArrivedIDList():
            if not routes:
                break
            k = len(departures)
            rid = f"{prefix}.r{k % len(routes)}"
            if rid not in known:
                sim.route.add(rid, routes[k % len(routes)])
                known.add(rid)
            sim.vehicle.add(f"{prefix}.{k}", rid, typeID="DEFAULT_VEHTYPE", depart="now")
            departures.append((now, routes[k % len(routes)]))
        ids = sim.vehicle.getIDList()
        acc = sums["settle" if step < n_settle else "probe"]
        acc[0] += sum(sim.vehicle.getSpeed(v) for v in ids)
        acc[1] += len(ids)
        if step >= n_settle:
            counts.append(len(ids))

    def mean(key):
        total, n = sums[key]
        return round(total / n, 3) if n else None
    record = {"settle_s": round(n_settle * dt, 3), "seconds": round(n_probe * dt, 3),
              "mean_speed_ms": mean("probe"), "settle_speed_ms": mean("settle"),
              "vehicles_mean": round(float(np.mean(counts)), 1), "vehicles_min": int(min(counts)),
              "replaced": len(departures), "waiting_to_enter": len(sim.simulation.getPendingVehicles())}
    return Probe(record, departures, float(sim.simulation.getTime()))


def _prepend_departures(path: str, departures: list) -> None:
    """Write ``departures`` (time, route) as vehicles into the randomTrips.py file ``path``, before its
    trips (which start after them: SUMO reads a route file's departures in order), of its vType."""
    from xml.sax.saxutils import quoteattr
    with open(path) as f:
        text = f.read()
    vtype = re.search(r'<vType id="([^"]+)"', text)
    typ = f' type="{vtype.group(1)}"' if vtype else ""
    rows = "".join(f'    <vehicle id="inflow_probe{i}" depart="{t:.2f}"{typ}><route edges={quoteattr(" ".join(r))}/>'
                   f'</vehicle>\n' for i, (t, r) in enumerate(departures))
    cut = min(i for i in (text.find("    <trip "), text.find("<trip "), text.rfind("</routes>")) if i >= 0)
    with open(path, "w") as f:
        f.write(text[:cut] + rows + text[cut:])


def write_inflow(path: str, net, vehicles: int, begin: float, seed: int, speed: float | None = None,
                 sample: list[list[str]] | None = None, probe: Probe | None = None,
                 fringe: bool | None = None) -> dict:
    """inflow.rou.xml: randomTrips.py trips from the fringe (or anywhere, for a network without
    one) at the rate that holds ``vehicles`` on the network: in a steady state as many enter as
    leave, ``vehicles / trip time`` per second (Little's law), offered :data:`SUPPLY` times over, the
    configurations capping the network at ``vehicles`` (``max_num_vehicles`` in the result) and
    dropping a vehicle that waited :data:`MAX_DEPART_DELAY_S` to enter (``max_depart_delay_s``).

    The trip time is the mean route length of a first sample of the same random trips (``sample``,
    else drawn here: :func:`inflow_sample`) over ``speed`` (m/s; default the ``probe``'s), the
    filled network's measured mean speed, but never shorter than those routes at free flow (0.7 x
    the speed limits: a rate too high feeds itself, more vehicles, slower trips, gridlock). Without
    a speed the free-flow time alone. With a ``probe`` its replacements are the file's first
    departures (they kept the filled number while the seeded vehicles left) and the trips at the
    rate follow from its end."""
    if vehicles <= 0:
        return {"file": None, "reason": "no vehicles to hold"}
    sources = fringe_sources(net)
    if sample is None:
        sample, fringe = inflow_sample(net, begin, seed, vehicles)
    elif fringe is None:
        fringe = bool(sources)
    free_s, metres = trip_seconds(net, sample), route_metres(net, sample)
    if free_s <= 0 or metres <= 0:
        return {"file": None, "reason": "randomTrips.py found no route"}
    if speed is None and probe is not None:
        speed = probe.speed
    measured_s = metres / speed if speed else None
    trip_s = max(free_s, measured_s or 0.0)
    period = max(trip_s / vehicles / SUPPLY, 0.1)
    steady = max(begin, probe.until) if probe is not None else begin
    _random_trips(net.path, path, steady, period, seed, fringe, end=begin + INFLOW_SECONDS)
    if probe is not None and probe.departures:
        _prepend_departures(path, probe.departures)
    rate = {"vehicles": vehicles, "sample_trips": len(sample), "route_m": round(metres, 1),
            "free_flow_trip_s": round(free_s, 1),
            "measured_speed_ms": None if speed is None else round(speed, 3),
            "measured_trip_s": None if measured_s is None else round(measured_s, 1),
            "trip_s_from": "measured" if measured_s is not None and measured_s >= free_s else "free flow",
            "supply": SUPPLY,
            "method": "period = trip_s / vehicles / supply (Little's law, offered supply times); trip_s = the "
                      "slower of route_m / the filled network's measured mean speed and the routes at 0.7 x the "
                      "speed limits; SUMO's max-num-vehicles holds the network at vehicles, its max-depart-delay "
                      "drops a surplus vehicle that waited max_depart_delay_s to enter"}
    out = {"file": os.path.basename(path), "period_s": round(period, 3), "trip_s": round(trip_s, 1),
           "from": "fringe" if fringe else "anywhere (the network has no fringe)" if not sources else
                   f"anywhere (the fringe's {len(sources)} edges cannot insert {1.0 / period:.2f} veh/s)",
           "fringe_sources": len(sources), "seconds": INFLOW_SECONDS, "max_num_vehicles": vehicles,
           "max_depart_delay_s": MAX_DEPART_DELAY_S, "rate": rate}
    if probe is not None:
        rate["probe"] = probe.record
        out["probe_departures"] = len(probe.departures)
        out["steady_from"] = round(steady, 3)
    return out


__all__ = ["MAX_DEPART_DELAY_S", "MAX_REFUSED_AT_LOAD", "PROBE_SECONDS", "admit_start", "load_each", "refuse_at_load", "remove_vehicle", "SETTLE_SECONDS", "InflowError", "Probe", "fringe_capacity", "fringe_sources", "inflow_sample", "probe_speed",
           "route_metres", "seed_fill", "trip_seconds", "write_inflow", "write_start_routes"]
