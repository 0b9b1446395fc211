"""Whole-network fill with demand (python -m sumo_scendiff.fill -r/-c): the demand estimate, the
demand's own vehicles put on their lanes, their routes and vTypes. Real model, real SUMO."""
from __future__ import annotations

import math
import os
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from .test_fill import NET, NET4, _fail, _fill

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"


def test_demand_estimate(tmp_path):
    """Vehicles departed before T and still on their route at free flow count; those arrived or
    not yet departed do not."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.map.network import Network
    net = Network.load(NET)
    edges = [e.getID() for e in net.sumo_net.getEdges() if e.getFromNode().getID() != e.getToNode().getID()]
    e = edges[0]
    routes = tmp_path / "d.rou.xml"
    routes.write_text(f'<routes><vehicle id="a" depart="95"><route edges="{e}"/></vehicle>'
                      f'<vehicle id="b" depart="0"><route edges="{e}"/></vehicle>'
                      f'<vehicle id="c" depart="200"><route edges="{e}"/></vehicle></routes>')
    est = DemandEstimate.at(net, [str(routes)], begin=100.0)
    assert est.on_edge == {e: 1} and est.departed == 2


def test_departures_before_the_state_are_the_fills(tmp_path):
    """With ``due`` (the state's time, a seeding step after T) the departures before it count as
    departing at T; one at ``due`` is left to the route file, as SUMO started from the state loads it."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.map.network import Network
    net = Network.load(NET)
    e = [e.getID() for e in net.sumo_net.getEdges() if e.getFromNode().getID() != e.getToNode().getID()]
    routes = tmp_path / "d.rou.xml"
    routes.write_text("<routes>" + "".join(f'<vehicle id="{v}" depart="{t}"><route edges="{e[k]}"/></vehicle>'
                                           for k, (v, t) in enumerate([("at", 100), ("within", 100.25),
                                                                       ("due", 100.5)])) + "</routes>")
    assert {r.id for r in DemandEstimate.at(net, [str(routes)], begin=100.0).en_route} == {"at"}
    est = DemandEstimate.at(net, [str(routes)], begin=100.0, due=100.5)
    assert {r.id for r in est.en_route} == {"at", "within"} and all(r.since == 0.0 for r in est.en_route)


def test_no_demand_vehicle_twice(tmp_path):
    """A fill at T carries the demand's departures before its state's time (T + one step), and both
    configurations start at that time, so SUMO loads none of them again from the route files: each
    demand vehicle departs once, a later one from its file."""
    from sumo_scendiff.map.network import Network
    edges = [e.getID() for e in Network.load(NET).sumo_net.getEdges() if e.getLength() > 40]
    demand = tmp_path / "demand.rou.xml"
    times = [("early", 60), ("at", 120), ("within", 120.25), ("due", 120.5), ("later", 125)]
    demand.write_text("<routes>" + "".join(f'<vehicle id="{v}" depart="{t}"><route edges="{edges[k]}"/></vehicle>'
                                           for k, (v, t) in enumerate(times)) + "</routes>")
    # a 0.5 s step (a demand's own default is SUMO's 1 s): "due" departs after the state's time
    doc = _fill(tmp_path / "o", "--demand-estimate", "-r", str(demand), "--begin", "120", "--step-length", "0.5")
    carried = {a["demand"]["id"] for a in doc["agents"] if a.get("demand") and a["vehicle"]}
    assert {"at", "within"} <= carried and not carried & {"due", "later"}
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        begin, _, departed = replayed(str(tmp_path / "o" / cfg), 130.0)
        assert begin == pytest.approx(doc["state_time"], abs=0.51)
        from_file = [v for v in departed if v in dict(times)]
        assert sorted(from_file) == ["due", "later"], cfg


def replayed(cfg: str, until: float) -> tuple[float, set[str], list[str]]:
    """Stock SUMO (libsumo) on ``cfg``: the time it starts at, the vehicles there then, and the
    vehicles departing from then until ``until``."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    libsumo.start([sumo_binary(), "-c", cfg, "--no-step-log", "true"])
    try:
        begin, present, departed = libsumo.simulation.getTime(), set(libsumo.vehicle.getIDList()), []
        while libsumo.simulation.getTime() < until:
            libsumo.simulationStep()
            departed += libsumo.simulation.getDepartedIDList()
    finally:
        libsumo.close()
    return begin, present, departed


def _edge_pair(net):
    """An edge with two car lanes or more and a successor, from a lane that leads there."""
    for e in net.sumo_net.getEdges():
        if e.getLaneNumber() < 2 or e.getLength() < 60:
            continue
        for nxt in e.getOutgoing():
            if nxt.getToNode() is not e.getFromNode():
                return e, nxt
    raise AssertionError("no such edge")


def test_en_route_vehicles_on_their_lanes():
    """The demand's vehicles: on a lane that leads to their next edge, waiting ones queued from the
    stop line (longest waiting first), moving ones where they have driven to, none overlapping;
    sizes and gaps from the vTypes."""
    from sumo_scendiff.fill.demand import DemandEstimate, EnRoute
    from sumo_scendiff.fill.en_route import STOP_MARGIN, place_en_route
    from sumo_scendiff.fill.vtypes import DEFAULT_MIN_GAP as MIN_GAP
    from sumo_scendiff.fill.vtypes import Body
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    e, nxt = _edge_pair(net)
    route = (e.getID(), nxt.getID())
    travel = e.getLength() / 10.0
    vehicles = [EnRoute(f"w{k}", "truck" if k == 1 else None, route, travel + 5.0 * (3 - k), travel, 10.0)
                for k in range(3)] + [EnRoute("m0", None, route, 2.0, travel, 10.0),
                                      EnRoute("m1", None, route, 2.1, travel, 10.0)]
    placed, skipped = place_en_route(net, DemandEstimate(0.0, {}, 5, 0, 5, vehicles), {"truck": Body(10.0, 2.5, 1.0)})
    assert not skipped and [p.vehicle.id for p in placed] == ["w0", "w1", "w2", "m1", "m0"]
    ok_lanes = {c.getFromLane().getID() for c in e.getConnections(nxt)}
    by_lane = {}
    for p in placed:
        lane = net.lanes[p.lane]
        assert lane.edge == e.getID() and lane.id in ok_lanes
        by_lane.setdefault(p.lane, []).append(p)
        xy, _ = net.lane_pose(p.lane, p.pos - 0.5 * p.length)
        assert math.hypot(p.x - xy[0], p.y - xy[1]) < 1e-6
    assert {p.vehicle.id: (p.length, p.width) for p in placed}["w1"] == (10.0, 2.5)
    fronts = {p.vehicle.id: p.pos for p in placed}
    for ps in by_lane.values():   # along each lane: in order, the one behind its minGap back
        for a, b in zip(ps, ps[1:]):
            assert b.pos <= a.pos - a.length - (1.0 if b.vehicle.id == "w1" else MIN_GAP) + 1e-9
    first = max(fronts[f"w{k}"] for k in range(3))
    assert first == pytest.approx(net.lanes[placed[0].lane].length - STOP_MARGIN)
    lane_of = {p.vehicle.id: p.lane for p in placed}
    assert fronts["m1"] == pytest.approx(21.0)     # 2.1 s at 10 m/s; m0 there too unless m1 is ahead
    assert fronts["m0"] == pytest.approx(20.0 if lane_of["m0"] != lane_of["m1"] else 21.0 - 5.0 - MIN_GAP)


def test_a_queue_longer_than_its_edge_stands_back_over_the_route_before_it():
    """Waiting vehicles that do not fit on their edge queue back onto the route's edges before it,
    the nearest first (their route then starts there); without an edge before, they are skipped."""
    from sumo_scendiff.fill.demand import DemandEstimate, EnRoute
    from sumo_scendiff.fill.en_route import place_en_route
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    e, nxt = _edge_pair(net)
    before = next(p for p in e.getIncoming() if p.getFromNode() is not e.getToNode())
    route = (e.getID(), nxt.getID())
    room = {ed.getID(): len({c.getFromLane().getID() for c in ed.getConnections(to)}) * ed.getLength() / 7.5
            for ed, to in ((e, nxt), (before, e))}
    n = int(room[e.getID()]) + 6      # more than the edge holds at 5 m + 2.5 m each
    queue = [EnRoute(f"q{k:02d}", None, route, 100.0 + n - k, 10.0, 10.0, (before.getID(),)) for k in range(n)]
    placed, skipped = place_en_route(net, DemandEstimate(0.0, {}, n, 0, n, queue))
    assert not skipped and len(placed) == n
    back = [p for p in placed if p.vehicle.edges[0] == before.getID()]
    assert back and all(p.vehicle.edges == (before.getID(),) + route for p in back)
    assert all(net.lanes[p.lane].edge == before.getID() for p in back)
    on_e = [p for p in placed if p.vehicle.edges[0] == e.getID()]
    assert max(int(p.vehicle.id[1:]) for p in on_e) < min(int(p.vehicle.id[1:]) for p in back)  # the front of the queue
    alone = [EnRoute(v.id, None, route, v.since, 10.0, 10.0) for v in queue]
    placed, skipped = place_en_route(net, DemandEstimate(0.0, {}, n, 0, n, alone))
    assert len(placed) == len(on_e) and len(skipped) == n - len(on_e)
    # longer than both: on to the edge before that one
    further = next(p for p in before.getIncoming() if p.getFromNode() is not before.getToNode())
    n = int(room[e.getID()] + room[before.getID()]) + 6
    queue = [EnRoute(f"q{k:02d}", None, route, 100.0 + n - k, 10.0, 10.0, (before.getID(), further.getID()))
             for k in range(n)]
    placed, skipped = place_en_route(net, DemandEstimate(0.0, {}, n, 0, n, queue))
    assert not skipped and len(placed) == n
    assert {p.vehicle.edges[0] for p in placed} == {e.getID(), before.getID(), further.getID()}
    assert all(p.vehicle.edges == (further.getID(), before.getID()) + route
               for p in placed if p.vehicle.edges[0] == further.getID())


def test_a_lane_both_directions_share_takes_one_of_them(tmp_path):
    """On a road whose two edges are each other's ``bidi`` (one lane, both directions on it), the
    demand's vehicles of one direction are placed there, the oncoming one stands back on the edge
    before (or is skipped): never face to face on the shared lane, which SUMO counts as a frontal
    collision in the first step. A lane of an edge's own goes before a shared one."""
    from sumo_scendiff.fill.demand import DemandEstimate, EnRoute
    from sumo_scendiff.fill.en_route import place_en_route
    from sumo_scendiff.map.network import Network
    from .conftest import netconvert
    nodes = ('<node id="ww" x="-400" y="0"/><node id="w" x="-200" y="0"/><node id="c" x="0" y="0"/>'
             '<node id="e" x="200" y="0"/>')
    edges = ('<edge id="a" from="w" to="c" numLanes="1" speed="13.89" spreadType="center" bidi="-a"/>'
             '<edge id="-a" from="c" to="w" numLanes="1" speed="13.89" spreadType="center" bidi="a"/>'
             '<edge id="in" from="ww" to="w" numLanes="1" speed="13.89"/>'
             '<edge id="out" from="w" to="ww" numLanes="1" speed="13.89"/>'
             '<edge id="b" from="c" to="e" numLanes="1" speed="13.89"/>'
             '<edge id="-b" from="e" to="c" numLanes="1" speed="13.89"/>')
    net = Network.load(netconvert(nodes, edges, str(tmp_path / "bidi.net.xml")))
    lane = {ln.id: i for i, ln in enumerate(net.lanes)}
    assert net.shared_lanes == {lane["a_0"]: lane["-a_0"], lane["-a_0"]: lane["a_0"]}
    east = EnRoute("east", None, ("a", "b"), 25.0, 20.0, 10.0)                  # waiting at c
    west = EnRoute("west", None, ("-a", "out"), 5.0, 20.0, 10.0, ("-b",))        # 50 m into -a
    placed, skipped = place_en_route(net, DemandEstimate(0.0, {}, 2, 0, 2, [east, west]))
    where = {p.vehicle.id: net.lanes[p.lane].edge for p in placed}
    assert where["east"] == "a" and where.get("west") in ("-b", None)
    assert len(placed) + len(skipped) == 2
    alone, _ = place_en_route(net, DemandEstimate(0.0, {}, 1, 0, 1, [west]))
    assert [net.lanes[p.lane].edge for p in alone] == ["-a"]


def test_a_bicycle_rides_its_bike_lane_not_a_car_lane(tmp_path):
    """An edge with a bike lane and a car lane that forbids bicycles: the demand's bicycle is not
    put on the car lane (SUMO would refuse it there); its car is."""
    from sumo_scendiff.fill.demand import DemandEstimate, EnRoute
    from sumo_scendiff.fill.en_route import place_en_route
    from sumo_scendiff.map.network import Network
    from .conftest import netconvert
    nodes = '<node id="w" x="-200" y="0"/><node id="c" x="0" y="0"/><node id="e" x="200" y="0"/>'
    edges = ('<edge id="a" from="w" to="c" numLanes="2" speed="13.89"><lane index="0" allow="bicycle"/>'
             '<lane index="1" disallow="bicycle"/></edge><edge id="b" from="c" to="e" numLanes="1" speed="13.89"/>')
    net = Network.load(netconvert(nodes, edges, str(tmp_path / "bike.net.xml")))
    bike = EnRoute("bike", "bk", ("a", "b"), 5.0, 20.0, 5.0)
    car = EnRoute("car", "car", ("a", "b"), 5.0, 20.0, 10.0)
    est = DemandEstimate(0.0, {"a": 2}, 2, 0, 2, [bike, car])
    placed, skipped = place_en_route(net, est, classes={"bk": "bicycle", "car": "passenger"})
    assert [p.vehicle.id for p in placed] == ["car"] and net.lanes[placed[0].lane].id == "a_1"
    assert [v.id for v in skipped] == ["bike"]


def test_vtype_bodies(tmp_path):
    """A vType's length, width and minGap, SUMO's default for its vClass where it gives none, and a
    distribution's first member's."""
    from sumo_scendiff.fill.vtypes import Body, vtype_bodies
    f = tmp_path / "t.add.xml"
    f.write_text('<additional><vType id="a" length="4.2" width="1.7" minGap="1.5"/><vType id="b" vClass="bus"/>'
                 '<vTypeDistribution id="d"><vType id="c" vClass="truck" probability="1"/></vTypeDistribution>'
                 '<vTypeDistribution id="e" vTypes="b a"/><vType id="f" vClass="bicycle"/></additional>')
    assert vtype_bodies([str(f)]) == {"a": Body(4.2, 1.7, 1.5), "b": Body(12.0, 2.5), "c": Body(7.1, 2.4),
                                      "d": Body(7.1, 2.4), "e": Body(12.0, 2.5), "f": Body(1.6, 0.65, 0.5)}
    assert Body(4.2, 1.7, 1.5).spacing == pytest.approx(5.7)


def test_fill_with_demand(tmp_path):
    """-r: the demand's level at --begin is the density source (recorded; applied only with a
    density model), no inflow is drawn, and the demand continues in both configurations. The
    fill's vehicles are the demand's own (fill.json names them) and drive their own routes on."""
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.map.network import Network
    snet = Network.load(NET).sumo_net
    edges = sorted(e.getID() for e in snet.getEdges())
    demand = tmp_path / "demand.rou.xml"
    demand.write_text(f'<routes><vType id="calm" accel="1.2" sigma="0.1" color="0,0,255"/>'
                      f'<flow id="f" type="calm" begin="0" end="600" period="4" from="{edges[0]}" '
                      f'to="{edges[-1]}"/></routes>')
    doc = _fill(tmp_path / "o", "--demand-estimate", "-r", str(demand), "--begin", "120")
    src = doc["density"]
    assert src["kind"] == "demand" and src["time"] == 120 and src["en_route"] > 0
    assert doc["inflow"]["file"] is None and not os.path.exists(tmp_path / "o" / "inflow.rou.xml")
    mine = [a for a in doc["agents"] if a.get("demand")]
    v = src["vehicles"]
    assert v["placed"] + v["no_room"] + v["no_car_lane"] + v["outside"] == src["en_route"]
    assert len(mine) >= 0.9 * src["vehicles"]["placed"] and all(a["demand"]["id"].startswith("f.") for a in mine)
    start = ET.parse(tmp_path / "o" / "start.rou.xml").getroot()
    named = {r.get("id"): r.get("edges") for r in start.iter("route")}
    edges_of = {v.get("id"): (v.find("route").get("edges") if v.find("route") is not None else named[v.get("route")])
                for v in start.iter("vehicle")}
    followed = [a for a in mine if a["demand"]["route"] == "followed"]
    assert len(followed) >= 0.7 * len(mine)
    assert all(edges_of[a["vehicle"]].split()[-1] == edges[-1] for a in followed)   # the flow's destination
    # they drive with the demand's vType: in the state, and in the portable start
    types = {t.get("id"): t for t in start.iter("vType")}
    vtype_of = {v.get("id"): v.get("type") for v in start.iter("vehicle")}
    assert all(types[vtype_of[a["vehicle"]]].get("accel") == "1.2" for a in mine if a["vehicle"] in vtype_of)
    import libsumo
    libsumo.start([sumo_binary(), "-c", str(tmp_path / "o" / "scenario.sumocfg"), "--no-step-log", "true"])
    try:
        present = set(libsumo.vehicle.getIDList())
        accels = [libsumo.vehicletype.getAccel(libsumo.vehicle.getTypeID(a["vehicle"])) for a in mine
                  if a["vehicle"] in present]
    finally:
        libsumo.close()
    assert accels and all(a == pytest.approx(1.2) for a in accels)
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        assert "demand.rou.xml.gz" in (tmp_path / "o" / cfg).read_text()
        run = subprocess.run([sumo_binary(), "-c", str(tmp_path / "o" / cfg), "--end", "130"],
                             check=False, capture_output=True, text=True, timeout=60)
        assert run.returncode == 0 and "Error" not in run.stderr, run.stderr


def test_a_bus_keeps_the_stops_ahead_of_it(tmp_path):
    """A bus line whose stop is on its last edge: each bus the fill seeds before that edge still has
    the stop, in the saved state and in the portable start, and stock SUMO runs both."""
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.map.network import Network
    snet = Network.load(NET).sumo_net
    edges = sorted(e.getID() for e in snet.getEdges() if e.allows("bus"))
    last = snet.getEdge(edges[-1])
    (tmp_path / "stops.add.xml").write_text(f'<additional><busStop id="bs" lane="{last.getLanes()[0].getID()}" '
                                            f'startPos="{last.getLength() - 25:.1f}" endPos="{last.getLength() - 5:.1f}"/>'
                                            '</additional>')
    (tmp_path / "bus.rou.xml").write_text(
        f'<routes><vType id="coach" vClass="bus"/><flow id="L1" type="coach" line="1" begin="0" end="600" '
        f'period="15" from="{edges[0]}" to="{edges[-1]}"><stop busStop="bs" duration="20"/></flow></routes>')
    doc = _fill(tmp_path / "o", "--demand-estimate", "-r", str(tmp_path / "bus.rou.xml"), "-a", str(tmp_path / "stops.add.xml"),
                "--begin", "120")
    buses = [a["vehicle"] for a in doc["agents"] if a.get("demand") and a["vehicle"]]
    assert buses
    start = (tmp_path / "o" / "start.rou.xml").read_text()
    assert start.count('<stop busStop="bs"') >= 1
    import libsumo
    libsumo.start([sumo_binary(), "-c", str(tmp_path / "o" / "scenario.sumocfg"), "--no-step-log", "true"])
    try:
        ahead = [v for v in buses if libsumo.vehicle.getRoadID(v) != edges[-1]]
        with_stop = [v for v in ahead if [s.stoppingPlaceID for s in libsumo.vehicle.getStops(v)] == ["bs"]]
    finally:
        libsumo.close()
    assert ahead and len(with_stop) == len(ahead)
    assert start.count('<stop busStop="bs"') >= len(ahead)
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        run = subprocess.run([sumo_binary(), "-c", str(tmp_path / "o" / cfg), "--end", "200"],
                             check=False, capture_output=True, text=True, timeout=60)
        assert run.returncode == 0 and "Error" not in run.stderr, run.stderr


@pytest.mark.parametrize("begin, asked", [("30", "30 s (0:00:30)"), ("0:00:45", "45 s (0:00:45)")])
def test_a_start_outside_the_demand_is_refused(tmp_path, capsys, begin, asked):
    """--begin before the first departure (seconds or SUMO's clock time): one line naming the flag
    and the demand's span, exit 2, no folder. (After the last departure the demand's vehicles may
    still drive: that is SUMO's to run, tests/test_scenario.py.)"""
    from sumo_scendiff.map.network import Network
    edges = sorted(e.getID() for e in Network.load(NET).sumo_net.getEdges())
    demand = tmp_path / "demand.rou.xml"
    demand.write_text(f'<routes><flow id="f" begin="0:01:00" end="600" period="4" from="{edges[0]}" '
                      f'to="{edges[-1]}"/></routes>')
    err = _fail(capsys, "-n", NET, "-r", str(demand), "--begin", begin, "-o", str(tmp_path / "o"))
    assert err.endswith(f"--begin {asked} lies outside the demand ({demand}: departures from 60 s (0:01:00) "
                        "to 600 s (0:10:00)); give a --begin within it")
    assert not os.path.exists(tmp_path / "o")


def test_demand_level_only(tmp_path):
    """--demand-level-only: the demand's level per tile, no vehicle of its own in the fill."""
    from sumo_scendiff.map.network import Network
    edges = sorted(e.getID() for e in Network.load(NET).sumo_net.getEdges())
    demand = tmp_path / "demand.rou.xml"
    demand.write_text(f'<routes><flow id="f" begin="0" end="600" period="4" from="{edges[0]}" '
                      f'to="{edges[-1]}"/></routes>')
    doc = _fill(tmp_path / "o", "--demand-estimate", "-r", str(demand), "--begin", "120", "--demand-level-only")
    assert doc["density"]["kind"] == "demand" and "vehicles" not in doc["density"]
    assert doc["agents"] and not any("demand" in a for a in doc["agents"])


def test_times_in_sumos_h_m_s_form(tmp_path):
    """SUMO reads a time as seconds or h:m:s: a departure at 0:01:40 is one at 100 s, and a light's
    phases and offset may be written so too."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.programs import signal_programs
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    e = max(net.sumo_net.getEdges(), key=lambda x: x.getLength())
    routes = tmp_path / "t.rou.xml"
    for depart in ("100", "0:01:40"):
        routes.write_text(f'<routes><vehicle id="a" depart="{depart}"><route edges="{e.getID()}"/></vehicle>'
                          f'<flow id="f" begin="0:01:00" end="0:02:00" period="30" departSpeed="0">'
                          f'<route edges="{e.getID()}"/></flow></routes>')
        est = DemandEstimate.at(net, [str(routes)], begin=101.0)
        assert est.departed == 3 and {v.id for v in est.en_route} >= {"a", "f.1"}   # (f.0 at 60 s)
        assert [v.since for v in est.en_route if v.id == "a"] == [pytest.approx(1.0)]
    add = tmp_path / "tls.add.xml"
    add.write_text('<additional><tlLogic id="J" type="static" programID="p" offset="0:00:10">'
                   '<phase duration="0:00:30" state="Gr"/><phase duration="30" state="rG"/></tlLogic></additional>')
    program = signal_programs([str(add)])["J"]
    assert program.offset == 10.0 and program.cycle == 60.0


def test_a_full_edge_holds_the_queue_back_and_the_insertions(tmp_path):
    """A lane holds its length over JAM_SPACING vehicles, and a queue stands on the lanes that lead
    on along its route: behind a light that stays red (an additional file's program) those lanes of
    the block before it fill, the queue spills back onto the edge before, and departures onto a full
    first edge wait to be inserted (not on the network yet)."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.queues import JAM_SPACING
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    red = tmp_path / "red.add.xml"
    red.write_text('<additional><tlLogic id="B1" type="static" programID="red" offset="0">'
                   f'<phase duration="90" state="{"r" * 20}"/></tlLogic></additional>')
    routes = tmp_path / "q.rou.xml"
    routes.write_text("<routes>" + "".join(
        f'<vehicle id="v{i:02d}" depart="{i}" departSpeed="max"><route edges="A0A1 A1B1 B1B0"/></vehicle>'
        for i in range(90)) + "</routes>")
    snet = net.sumo_net
    turn = [ln for ln in snet.getEdge("A1B1").getLanes() if any(c.getTo().getID() == "B1B0" for c in ln.getOutgoing())]
    onto = [ln for ln in snet.getEdge("A0A1").getLanes() if any(c.getToLane() in turn for c in ln.getOutgoing())]
    assert 1 <= len(turn) < len(snet.getEdge("A1B1").getLanes())     # the right turn leaves from one lane
    hold = {e: len(lanes) * math.ceil(snet.getEdge(e).getLength() / JAM_SPACING)
            for e, lanes in (("A0A1", onto), ("A1B1", turn))}
    est = DemandEstimate.at(net, [str(routes)], begin=600.0, additional=[str(red)])
    assert est.on_edge == hold and est.vehicles == sum(hold.values()) < 90
    first = sorted(v.id for v in est.en_route if v.edges[0] == "A1B1")
    assert first == [f"v{i:02d}" for i in range(hold["A1B1"])]       # first come, in front
    assert all(v.waiting for v in est.en_route)
    # the light as the network has it: the queue goes on, nobody waits to be inserted
    est = DemandEstimate.at(net, [str(routes)], begin=600.0)
    assert est.vehicles < 20


def test_fill_picture_is_framed_on_the_car_lanes(tmp_path):
    """A footpath running far beyond the roads does not shrink the picture of the fill to a corner."""
    from sumo_scendiff.fill.picture import draw_fill, frame
    from sumo_scendiff.map.network import Network

    from .conftest import netconvert
    path = netconvert('<node id="a" x="0" y="0"/><node id="b" x="200" y="0"/><node id="c" x="200" y="3000"/>',
                      '<edge id="ab" from="a" to="b" numLanes="1" speed="13.89"/>'
                      '<edge id="bc" from="b" to="c" numLanes="1" speed="2" allow="pedestrian"/>',
                      str(tmp_path / "foot.net.xml"))
    net = Network.load(path)
    x0, y0, x1, y1 = frame(net)
    assert net.bounds[3] > 2900 and y1 < 50 and x1 - x0 > 150
    rows = np.array([[100.0, -1.6, 0.0, 4.5, 1.8]])
    draw_fill(str(tmp_path / "fill.png"), net, rows, [], "footpath")
    assert os.path.getsize(tmp_path / "fill.png") > 1000
