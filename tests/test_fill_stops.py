"""The demand estimate's vehicles at their stops (``fill --demand-estimate``): one the clock has at a
stop of a lane, a stop of one edge (``edge=``: SUMO picks the lane) or parked in a parkingArea at T
stands (or parks, off the lane) there in the fill's start as in SUMO's own run, and leaves when the
rest of its duration is over, within a few seconds of SUMO's own. Real SUMO, real model, a tiny grid."""
from __future__ import annotations

import json

import pytest

from .conftest import netconvert
from .test_fill_robust import _netgenerate

BEGIN = 300
LEAVE_S = 8.0     # s: the clock's arrival at a stop against SUMO's (its cruise and braking are estimates)
# three lines on the grid: a stop of a lane, a parking area (a car parked 75 s), a stop of one edge;
# at BEGIN each has vehicles that have stood long at their stop (9-65 s in SUMO's own run)
ROUTES = """<routes>
  <route id="r1" edges="A0A1 A1A2 A2A3 A3B3"/><route id="r2" edges="B0B1 B1B2 B2B3 B3C3"/>
  <route id="r3" edges="C0C1 C1C2 C2C3 C3D3"/>
  <flow id="lane" begin="0" end="900" period="60" route="r1"><stop lane="A1A2_0" endPos="80" duration="50"/></flow>
  <flow id="park" begin="5" end="900" period="30" route="r2"><stop parkingArea="pa" duration="75" parking="true"/></flow>
  <flow id="edge" begin="10" end="900" period="60" route="r3"><stop edge="C1C2" endPos="90" duration="50"/></flow>
</routes>"""


@pytest.fixture(scope="module")
def stop_fill(tmp_path_factory):
    d = tmp_path_factory.mktemp("stops")
    _netgenerate(str(d / "grid.net.xml"))
    (d / "stops.add.xml").write_text('<additional><parkingArea id="pa" lane="B1B2_0" startPos="40" endPos="100" '
                                     'roadsideCapacity="4"/></additional>')
    (d / "d.rou.xml").write_text(ROUTES)
    from sumo_scendiff.fill.__main__ import get_options, main
    assert main(get_options(["-n", str(d / "grid.net.xml"), "-r", str(d / "d.rou.xml"), "-a", str(d / "stops.add.xml"),
                             "--begin", str(BEGIN), "--demand-estimate", "-o", str(d / "o")])) == 0
    with open(d / "o" / "fill.json") as f:
        return d, json.load(f)


def _at_stops(args: list[str], names: dict | None, until: float) -> tuple[dict, dict]:
    """SUMO run to ``until``: demand id -> "parked" / "stopped" of the vehicles standing at a stop
    then, and demand id -> the time each of them leaves it. ``names``: SUMO id -> demand id."""
    import libsumo
    libsumo.start(args + ["--no-step-log", "true", "--no-warnings", "true"])
    try:
        while libsumo.simulation.getTime() < until:
            libsumo.simulationStep()
        name = (lambda v: names.get(v)) if names is not None else (lambda v: v)
        state = {name(v): "parked" if libsumo.vehicle.isStoppedParking(v) else "stopped"
                 for v in libsumo.vehicle.getIDList() if libsumo.vehicle.isStopped(v)}
        standing = {v for v in libsumo.vehicle.getIDList() if libsumo.vehicle.isStopped(v)}
        left: dict = {}
        while standing - set(left) and libsumo.simulation.getTime() < until + 200:
            libsumo.simulationStep()
            present = set(libsumo.vehicle.getIDList())
            left |= {v: libsumo.simulation.getTime() for v in standing - set(left)
                     if v not in present or not libsumo.vehicle.isStopped(v)}
    finally:
        libsumo.close()
    return state, {name(v): t for v, t in left.items()}


@pytest.mark.slow   # a real fill
def test_stops_and_parking_as_sumo_has_them(stop_fill):
    """A step into the fill's start (the seeded vehicles make their stops in the step after the
    seeding one, parked ones each in a lot of its own), the vehicles at a lane's stop, an edge's stop and parked are those SUMO's own run
    has there (parked off the lane where it parks them), and each leaves its stop within LEAVE_S of
    when SUMO's own lets it go: the rest of its duration, not the whole again."""
    from sumo_scendiff.core.tools import sumo_binary
    d, doc = stop_fill
    names = {a["vehicle"]: a["demand"]["id"] for a in doc["agents"] if a.get("demand") and a.get("vehicle")}
    until = BEGIN + 2
    own, own_left = _at_stops([sumo_binary(), "-n", str(d / "grid.net.xml"), "-r", str(d / "d.rou.xml"),
                               "-a", str(d / "stops.add.xml")], None, until)
    filled, filled_left = _at_stops([sumo_binary(), "-c", str(d / "o" / "scenario.sumocfg")], names, until)
    assert {k.split(".")[0] for k, how in own.items() if how == "stopped"} == {"lane", "edge"}
    assert sum(how == "parked" for how in own.values()) >= 2
    assert filled == own
    late = {v: filled_left[v] - own_left[v] for v in own}
    assert all(abs(dt) <= LEAVE_S for dt in late.values()), late


def test_a_stop_of_one_edge_is_on_the_lane_sumo_picks(tmp_path):
    """A stop of one edge (``edge=``, no lane) on an edge whose first lane is a sidewalk: the estimate
    puts it on the lane SUMO's own vehicle stops on (the first its class may use)."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.demand import on_lane
    from sumo_scendiff.map.network import Network
    net = netconvert('<node id="a" x="0" y="0"/><node id="b" x="300" y="0"/>',
                     '<edge id="ab" from="a" to="b" numLanes="2" speed="13.89" sidewalkWidth="2"/>',
                     str(tmp_path / "walk.net.xml"))
    stop = {"edge": "ab", "endPos": "150", "duration": "30"}
    (tmp_path / "d.rou.xml").write_text('<routes><vehicle id="v" depart="0"><route edges="ab"/>'
                                        '<stop edge="ab" endPos="150" duration="30"/></vehicle></routes>')
    libsumo.start([sumo_binary(), "-n", net, "-r", str(tmp_path / "d.rou.xml"), "--no-step-log", "true"])
    try:
        while not libsumo.vehicle.isStopped("v"):
            libsumo.simulationStep()
        lane = libsumo.vehicle.getLaneID("v")
    finally:
        libsumo.close()
    assert lane == "ab_1"
    assert on_lane(stop, Network.load(net).sumo_net, "passenger") == {"lane": lane, "endPos": "150", "duration": "30"}


def test_vehicles_at_their_stop_stand_on_its_lane(diagonal_net, tmp_path):
    """Buses standing at a stop on the left lane of a 2-lane road at T are placed there, on that
    lane, its first one's front at the stop's end (the least used lane would spread them over both)."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.en_route import AT_STOP_M, place_en_route
    from sumo_scendiff.map.network import Network
    net = Network.load(diagonal_net)
    (tmp_path / "stops.add.xml").write_text('<additional><busStop id="bs" lane="ab_1" startPos="150" endPos="250"/>'
                                            '</additional>')
    (tmp_path / "d.rou.xml").write_text('<routes><vType id="coach" vClass="bus"/><flow id="L" type="coach" begin="0" '
                                        'end="600" period="15"><route edges="ab"/><stop busStop="bs" duration="60"/>'
                                        '</flow></routes>')
    est = DemandEstimate.at(net, [str(tmp_path / "d.rou.xml")], 300.0, additional=[str(tmp_path / "stops.add.xml")])
    placed, _ = place_en_route(net, est)
    standing = sorted((p for p in placed if p.vehicle.stopped is not None), key=lambda p: -p.pos)
    assert len(standing) >= 2
    assert {net.lanes[p.lane].id for p in standing} == {"ab_1"}
    assert standing[0].pos == pytest.approx(250.0 - AT_STOP_M)


def _spaces_scenario(d) -> tuple:
    """(additional file, route file) in folder ``d``: a parking area of two roadside lots and four
    ``<space>``s at the end of B1B2 (docs: Simulation/ParkingArea), a car parking 75 s there every 15 s."""
    spaces = "".join(f'<space x="170" y="{y}" angle="90"/>' for y in (200, 210, 220, 230))
    add, routes = d / "pa.add.xml", d / "d.rou.xml"
    add.write_text(f'<additional><parkingArea id="pa" lane="B1B2_0" startPos="40" endPos="100" roadsideCapacity="2">'
                   f'{spaces}</parkingArea></additional>')
    routes.write_text('<routes><route id="r2" edges="B0B1 B1B2 B2B3 B3C3"/><flow id="park" begin="5" end="900" '
                      'period="15" route="r2"><stop parkingArea="pa" duration="75" parking="true"/></flow></routes>')
    return add, routes


def test_a_parking_area_with_spaces_fills_its_lots_as_sumo_does(tmp_path):
    """A parking area of two roadside lots and four ``<space>``s (docs: Simulation/ParkingArea): its
    capacity is SUMO's (roadside lots and spaces), and the estimate's cars parked there at T stand on
    its lane within the area, as each car SUMO parks there has its lane position within it (the spaces'
    cars at the space's own pose, off the road); the roadside lots past the second lie before the area."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.demand import DemandEstimate, parking_lots
    from sumo_scendiff.fill.en_route import place_en_route
    from sumo_scendiff.map.network import Network
    net_path = _netgenerate(str(tmp_path / "grid.net.xml"))
    add, routes = _spaces_scenario(tmp_path)
    libsumo.start([sumo_binary(), "-n", net_path, "-r", str(routes), "-a", str(add), "--no-step-log", "true",
                   "--no-warnings", "true"])
    try:
        while libsumo.simulation.getTime() < BEGIN:
            libsumo.simulationStep()
        capacity = int(libsumo.simulation.getParameter("pa", "parkingArea.capacity"))
        parked = {v: (libsumo.vehicle.getLanePosition(v), libsumo.vehicle.getPosition(v))
                  for v in libsumo.parkingarea.getVehicleIDs("pa")}
    finally:
        libsumo.close()
    assert len(parked) >= 4 and all(40.0 <= pos <= 100.0 for pos, _ in parked.values())
    assert sum(xy[0] == pytest.approx(170.0) for _, xy in parked.values()) >= 2    # in the spaces, off the road
    assert parking_lots([str(add)])["pa"].capacity == capacity == 6
    net = Network.load(net_path)
    est = DemandEstimate.at(net, [str(routes)], float(BEGIN), additional=[str(add)])
    placed, _ = place_en_route(net, est)
    at_pa = [p.pos for p in placed if p.vehicle.stopped is not None]
    assert len(at_pa) >= 4 and all(40.0 <= pos <= 100.0 for pos in at_pa), sorted(at_pa)


@pytest.mark.slow   # a real fill
def test_parked_cars_stay_parked_in_both_starts_of_sumos_own_run(tmp_path):
    """A fill from SUMO's own run to T (``--area``, no estimate): the cars parked in the parking area at
    T are in the portable start too, departing on the area's lane where they park and parked again in
    the step after (SUMO gives a parked car no lane: departing from the edge after, its stop would be
    behind it and SUMO refused the car), their later stops kept; fill.json counts what both starts hold."""
    import re

    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.__main__ import get_options, main
    _netgenerate(str(tmp_path / "grid.net.xml"))
    (tmp_path / "stops.add.xml").write_text('<additional><parkingArea id="pa" lane="B1B2_0" startPos="40" '
                                            'endPos="100" roadsideCapacity="4"/></additional>')
    (tmp_path / "d.rou.xml").write_text(ROUTES)
    out = tmp_path / "o"
    assert main(get_options(["-n", str(tmp_path / "grid.net.xml"), "-r", str(tmp_path / "d.rou.xml"),
                             "-a", str(tmp_path / "stops.add.xml"), "--begin", str(BEGIN),
                             "--area=-10,-10,460,460", "-o", str(out)])) == 0
    with open(out / "fill.json") as f:
        doc = json.load(f)
    seeded = {a["vehicle"] for a in doc["agents"] if a["vehicle"] is not None}
    assert doc["summary"]["vehicles"] == len(seeded) and doc["summary"]["refused"] == 0

    def parked(config: str, steps: int) -> tuple[set, set]:
        libsumo.start([sumo_binary(), "-c", str(out / config), "--no-step-log", "true", "--no-warnings", "true"])
        try:
            present = set(libsumo.vehicle.getIDList())
            for _ in range(steps):
                libsumo.simulationStep()
            return present, {v for v in libsumo.vehicle.getIDList() if libsumo.vehicle.isStoppedParking(v)}
        finally:
            libsumo.close()
    in_state, parked_state = parked("scenario.sumocfg", 0)
    portable = set(re.findall(r'<vehicle id="start\.([^"]+)"', (out / "start.rou.xml").read_text()))
    assert in_state == seeded == portable
    assert len(parked_state) >= 2
    _, parked_start = parked("start.sumocfg", 2)
    assert {v.removeprefix("start.") for v in parked_start} >= parked_state
    # their later stops kept, the parked one's duration what is left of it
    for vid in parked_state:
        car = re.search(rf'<vehicle id="start\.{re.escape(vid)}".*?</vehicle>', (out / "start.rou.xml").read_text(), re.S)
        assert car and 'parkingArea="pa"' in car.group(0) and float(re.search(r'duration="([^"]+)"', car.group(0))[1]) < 75


@pytest.mark.slow   # a real fill
def test_cars_in_the_spaces_of_a_parking_area_are_parked_in_the_first_step(tmp_path):
    """The estimate's cars parked at T in a parking area's ``<space>``s: SUMO enters every space from the
    area's end, so the fill seeds them all there (their boxes on one another for the seeding step) and
    SUMO parks them together in the start's first step, as its own run has them parked at T; seeded one
    behind the other on the lane they parked 11, 17 and 22 s late, one after another."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.__main__ import get_options, main
    net = _netgenerate(str(tmp_path / "grid.net.xml"))
    add, routes = _spaces_scenario(tmp_path)
    out = tmp_path / "o"
    assert main(get_options(["-n", net, "-r", str(routes), "-a", str(add), "--begin", str(BEGIN), "--demand-estimate",
                             "-o", str(out)])) == 0

    def parked(args: list[str]) -> tuple[int, int]:
        """(cars parked at pa, of them in a space off the road) once SUMO is at BEGIN + 2."""
        libsumo.start([sumo_binary(), *args, "--no-step-log", "true", "--no-warnings", "true"])
        try:
            while libsumo.simulation.getTime() < BEGIN + 2:
                libsumo.simulationStep()
            ids = libsumo.parkingarea.getVehicleIDs("pa")
            return len(ids), sum(libsumo.vehicle.getPosition(v)[0] == pytest.approx(170.0) for v in ids)
        finally:
            libsumo.close()
    own, filled = parked(["-n", net, "-r", str(routes), "-a", str(add)]), parked(["-c", str(out / "scenario.sumocfg")])
    # as many parked (SUMO's own run has freed a roadside lot its history knows and the estimate does not)
    assert own[1] >= 2 and filled[0] == own[0]
    with open(out / "fill.json") as f:
        moved = [a for a in json.load(f)["agents"] if "to_space_entry_m" in a]
    assert len(moved) == filled[1] >= 2 and all(a["status"] == "placed" for a in moved)


@pytest.mark.slow   # a real fill
def test_sumos_own_cars_in_a_parking_areas_spaces_park_together_in_the_portable_start(tmp_path):
    """From SUMO's own run: the cars parked at T in a parking area's ``<space>``s (each departing at the
    area's end, where SUMO enters them) are all parked again after the portable start's second step;
    with SUMO's insertion checks against the other cars they departed one step after another."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.__main__ import get_options, main
    net = _netgenerate(str(tmp_path / "grid.net.xml"))
    add, routes = _spaces_scenario(tmp_path)
    out = tmp_path / "o"
    assert main(get_options(["-n", net, "-r", str(routes), "-a", str(add), "--begin", str(BEGIN), "-o", str(out)])) == 0

    def parked(config: str, steps: int) -> set[str]:
        libsumo.start([sumo_binary(), "-c", str(out / config), "--no-step-log", "true", "--no-warnings", "true"])
        try:
            for _ in range(steps):
                libsumo.simulationStep()
            return {v.removeprefix("start.") for v in libsumo.parkingarea.getVehicleIDs("pa")}
        finally:
            libsumo.close()
    at_t = parked("scenario.sumocfg", 0)
    assert len(at_t) >= 5       # its two roadside lots and spaces
    assert parked("start.sumocfg", 2) == at_t
