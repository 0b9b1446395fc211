"""The continuing inflow of a fill without demand: randomTrips.py trips at the rate that holds the
filled number of vehicles (Little's law), the rate from the filled network's own measured speed.

    sample, fringe = inflow_sample(net, begin, seed, vehicles)       # the first random trips' routes
    probe = probe_speed(sim, sample)                                 # the filled SUMO driven on, measured
    doc = write_inflow("inflow.rou.xml", net, vehicles, begin, seed, sample=sample, probe=probe, fringe=fringe)

docs/fill.md ("The continuing inflow") has the steps and what each was measured against.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field

import numpy as np

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


class InflowError(RuntimeError):
    """randomTrips.py could not make the inflow (one line: its last message)."""


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


__all__ = ["FRINGE_LOAD", "INFLOW_SECONDS", "INSERT_HEADWAY_S", "MAX_DEPART_DELAY_S", "PROBE_SECONDS", "SAMPLE_TRIPS",
           "SETTLE_SECONDS", "SUPPLY", "TYPICAL_SPEED_FACTOR", "InflowError", "Probe", "fringe_capacity",
           "fringe_sources", "inflow_sample", "probe_speed", "route_metres", "trip_seconds", "write_inflow"]
