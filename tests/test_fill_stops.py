"""The demand estimate's vehicles at their stops (``fill --demand-estimate``): one the clock has at a
stop of a lane, a stop of one edge (``edge=``: SUMO picks the lane) or parked in a parkingArea at T
stands (or parks, off the lane) there in the fill's start as in SUMO's own run, and leaves when the
rest of its duration is over, within a few seconds of SUMO's own. Real SUMO, real model, a tiny grid."""
from __future__ import annotations

import json

import pytest

from .test_fill_robust import _netgenerate

pytestmark = pytest.mark.slow   # a real fill
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
