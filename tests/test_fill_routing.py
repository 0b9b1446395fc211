"""The demand's departures as SUMO reads and routes them (fill/routing.py, duarouter): every form of
a route file, departure speeds, stops, repeated routes. Real SUMO."""
from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow   # real SUMO runs: the fast tier is -m "not slow"


def test_every_form_of_a_route_file_is_routed_as_sumo_does(tmp_path, grid):
    """Trips through via edges, between junctions and TAZs, flows by rate, number, probability
    and a random period, vehicles on a routeDistribution or of a vTypeDistribution: SUMO's router
    gives each its route, so every one of them is en route in the estimate, and as many as SUMO
    has on the network. Trips between junctions only where the scenario sets junction-taz (SUMO
    refuses them otherwise); a vehicle departing on a trigger is left out and counted; a public
    transport vehicle is in; a gzip-compressed route file is read as SUMO reads it."""
    import libsumo

    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.routing import RoutingError, routed_departures
    add = tmp_path / "taz.add.xml"
    add.write_text('<additional><taz id="west" edges="A0A1 A1A2"/>'
                   '<taz id="east"><tazSource id="C2C1" weight="1"/><tazSink id="C1C0" weight="1"/></taz></additional>')
    routes = tmp_path / "forms.rou.xml"
    routes.write_text(
        '<routes><vTypeDistribution id="mix"><vType id="small" length="4" probability="0.7"/>'
        '<vType id="lorry" vClass="truck" length="10" probability="0.3"/></vTypeDistribution>'
        '<routeDistribution id="rd"><route id="rd0" edges="A0B0 B0C0" probability="0.5"/>'
        '<route id="rd1" edges="A0B0 B0B1" probability="0.5"/></routeDistribution>'
        '<flow id="dist" route="rd" type="mix" begin="0" end="600" vehsPerHour="240"/>'
        '<flow id="junc" fromJunction="C2" toJunction="A0" begin="0" end="600" number="60"/>'
        '<flow id="taz" fromTaz="west" toTaz="east" begin="0" end="600" probability="0.1"/>'
        '<flow id="exp" from="C0C1" to="A1A0" via="B1A1" begin="0" end="600" period="exp(0.1)"/>'
        '</routes>')
    net_path = grid.path
    with pytest.raises(RoutingError, match="junction-taz"):
        routed_departures(net_path, [str(routes)], [str(add)], until=300.0)
    deps, unrouted = routed_departures(net_path, [str(routes)], [str(add)], until=300.0, junction_taz=True)
    assert unrouted == 0 and all(d.depart <= 300.0 for d in deps)
    assert {d.id.split(".")[0] for d in deps} == {"dist", "junc", "taz", "exp"}
    assert {d.type for d in deps if d.id.startswith("dist")} <= {"small", "lorry"}
    assert all(d.edges in (("A0B0", "B0C0"), ("A0B0", "B0B1")) for d in deps if d.id.startswith("dist"))
    assert all("B1A1" in d.edges for d in deps if d.id.startswith("exp"))
    later, _ = routed_departures(net_path, [str(routes)], [str(add)], until=300.0, since=100.0, junction_taz=True)
    assert [d.id for d in later] == [d.id for d in deps if d.depart >= 100.0]
    est = DemandEstimate.at(grid, [str(routes)], 300.0, additional=[str(add)], junction_taz=True)
    assert {v.id.split(".")[0] for v in est.en_route} == {"dist", "junc", "taz", "exp"}
    cfg = tmp_path / "forms.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{net_path}"/><route-files value="{routes}"/>'
                   f'<additional-files value="{add}"/></input><processing><junction-taz value="true"/>'
                   '</processing></configuration>')
    libsumo.start(["sumo", "-c", str(cfg), "--no-step-log", "--no-warnings", "--seed", "1"])
    try:
        libsumo.simulationStep(300.0)
        sumo = len(libsumo.vehicle.getIDList())
    finally:
        libsumo.close()
    assert est.vehicles == pytest.approx(sumo, rel=0.3), (est.vehicles, sumo)
    (tmp_path / "broken.rou.xml").write_text("<routes><trip id='t' depart='0' from='A0B0'")
    with pytest.raises(RoutingError, match="duarouter"):
        routed_departures(net_path, [str(tmp_path / "broken.rou.xml")], until=300.0)
    (tmp_path / "typo.rou.xml").write_text('<routes><flow id="f" type="lorri" from="A0B0" to="B0C0" begin="0" '
                                           'end="60" period="10"/></routes>')
    with pytest.raises(RoutingError, match="vehicle type 'lorri' for flow 'f' is not known"):
        routed_departures(net_path, [str(tmp_path / "typo.rou.xml")], until=300.0)
    import gzip

    from sumo_scendiff.fill.en_route import write_vtypes
    packed = tmp_path / "trig.rou.xml.gz"
    with gzip.open(packed, "wt") as f:
        f.write('<routes><vType id="coach" vClass="bus"/><vehicle id="bus" type="coach" depart="triggered">'
                '<route edges="A0B0 B0C0"/></vehicle><vehicle id="v" depart="10"><route edges="A0B0 B0C0"/>'
                '</vehicle><vehicle id="line" type="coach" line="L1" depart="20"><route edges="A0B0 B0C0"/>'
                '</vehicle></routes>')
    deps, unrouted = routed_departures(net_path, [str(packed)], until=300.0)
    assert [d.id for d in deps] == ["v", "line"] and unrouted == 1      # a line's vehicle too
    assert write_vtypes([str(packed)], str(tmp_path / "types.add.xml")) == ["coach"]


@pytest.mark.parametrize("given", [None, "0", "max"])
def test_departs_as_sumo_inserts(grid, tmp_path, given):
    """Whether a demand's vehicle starts from standing is what SUMO does with it: its departSpeed,
    else SUMO's default (``default.departspeed``, which the installed SUMO's version sets), checked
    against the speed SUMO itself inserts it at on an empty road."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.routing import routed_departures
    attr = f' departSpeed="{given}"' if given else ""
    routes = tmp_path / "one.rou.xml"
    routes.write_text(f'<routes><vehicle id="v" depart="5"{attr}><route edges="A0B0 B0C0"/></vehicle></routes>')
    (dep,), _ = routed_departures(grid.path, [str(routes)], until=10.0)
    libsumo.start([sumo_binary(), "-n", grid.path, "-r", str(routes), "--no-step-log", "--no-warnings"])
    try:
        while "v" not in libsumo.simulation.getDepartedIDList():
            libsumo.simulationStep()
        speed = libsumo.vehicle.getSpeed("v")
    finally:
        libsumo.close()
    assert dep.standing == (speed == 0.0), (given, speed)


def test_a_configurations_default_depart_speed(grid, tmp_path):
    """A configuration's ``default.departspeed`` decides for the vehicles that give no departSpeed,
    as it does in SUMO: "0" from standing, "max" moving; a vehicle's own attribute still wins."""
    from sumo_scendiff.fill.routing import routed_departures
    routes = tmp_path / "two.rou.xml"
    routes.write_text('<routes><vehicle id="a" depart="5"><route edges="A0B0 B0C0"/></vehicle>'
                      '<vehicle id="b" depart="6" departSpeed="0"><route edges="A0B0 B0C0"/></vehicle></routes>')
    for default, standing in (("0", {"a": True, "b": True}), ("max", {"a": False, "b": True})):
        deps, _ = routed_departures(grid.path, [str(routes)], until=10.0, depart_speed=default)
        assert {d.id: d.standing for d in deps} == standing, default


def test_a_stop_holds_its_vehicle_in_the_estimate(grid, tmp_path):
    """Buses standing 60 s at a stop on their way: the estimate holds them there for it, about as
    many en route as SUMO has (without the stop, a minute's worth fewer)."""
    import libsumo

    from sumo_scendiff.fill.demand import DemandEstimate
    stop = '<stop lane="B0C0_0" endPos="80" duration="60"/>'
    for name, body in (("stop", stop), ("none", "")):
        (tmp_path / f"{name}.rou.xml").write_text(
            f'<routes><vType id="coach" vClass="bus"/><flow id="L" type="coach" begin="0" end="600" period="10" '
            f'departSpeed="max"><route edges="A0B0 B0C0 C0C1"/>{body}</flow></routes>')
    with_stop = DemandEstimate.at(grid, [str(tmp_path / "stop.rou.xml")], 300.0).vehicles
    without = DemandEstimate.at(grid, [str(tmp_path / "none.rou.xml")], 300.0).vehicles
    libsumo.start(["sumo", "-n", grid.path, "-r", str(tmp_path / "stop.rou.xml"), "--no-step-log", "--no-warnings"])
    try:
        libsumo.simulationStep(300.0)
        sumo = libsumo.vehicle.getIDCount()
    finally:
        libsumo.close()
    assert with_stop - without >= 5
    assert with_stop == pytest.approx(sumo, rel=0.2), (with_stop, sumo)


def test_a_repeated_route_is_driven_its_times_over(grid, tmp_path):
    """A loop with ``repeat="2"`` is driven three times (duarouter writes it once, without the
    attribute), so the estimate keeps its vehicles on the loop as SUMO does."""
    from sumo_scendiff.fill.routing import routed_departures
    loop = "A0B0 B0B1 B1A1 A1A0"
    (tmp_path / "loop.rou.xml").write_text(f'<routes><route id="loop" edges="{loop}" repeat="2"/>'
                                           '<flow id="f" begin="0" end="60" period="30" route="loop"/>'
                                           '<vehicle id="once" depart="5"><route edges="A0B0 B0C0"/></vehicle></routes>')
    deps, _ = routed_departures(grid.path, [str(tmp_path / "loop.rou.xml")], until=100.0)
    edges = {d.id: d.edges for d in deps}
    assert edges["f.0"] == tuple(loop.split()) * 3 and edges["once"] == ("A0B0", "B0C0")


INCLUDED_FLAWS = {"missing": None, "empty": "",
                  "mismatched": ('<routes>\n    <vehicle id="i1" depart="1"><route edges="A0B0 B0C0"/></vehicle>\n'
                                 '    <vehicle id="i2" depart="2"><route edges="A0B0 B0C0"/></vehicl>\n</routes>\n'),
                  "cut": '<routes>\n    <vehicle id="i1" depart="1"><route edges="A0B0 B0C0"/></vehicle>\n    <veh'}


@pytest.mark.parametrize("flaw", list(INCLUDED_FLAWS))
def test_an_included_files_flaw_is_read_past_as_sumo_reads_it(grid, tmp_path, flaw):
    """A route file includes one (in another folder) that includes a file missing, empty, not
    well-formed or cut short: SUMO reports it, keeps its whole elements before the flaw and reads on;
    duarouter quits on it. The estimate routes what SUMO departs, the user's files untouched."""
    import subprocess
    import xml.etree.ElementTree as ET

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.routing import routed_departures
    (tmp_path / "sub").mkdir()
    if INCLUDED_FLAWS[flaw] is not None:
        (tmp_path / "sub" / "inc.rou.xml").write_text(INCLUDED_FLAWS[flaw])
    (tmp_path / "sub" / "mid.rou.xml").write_text(
        '<routes>\n    <vType id="slow" maxSpeed="5"/>\n    <include href="inc.rou.xml"/>\n'
        '    <vehicle id="m" type="slow" depart="3"><route edges="B0B1 B1B2"/></vehicle>\n</routes>\n')
    main = tmp_path / "main.rou.xml"
    main.write_text('<routes>\n    <vehicle id="a" depart="0"><route edges="A0B0 B0C0"/></vehicle>\n'
                    '    <include href="sub/mid.rou.xml"/>\n'
                    '    <flow id="f" begin="4" end="20" period="8" from="C1B1" to="B1A1"/>\n</routes>\n')
    before = {p: p.read_bytes() for p in tmp_path.rglob("*.xml")}
    trips = tmp_path / "trips.xml"
    done = subprocess.run([sumo_binary("sumo"), "-n", grid.path, "-r", str(main), "--end", "100", "--no-step-log",
                           "--tripinfo-output", str(trips)], capture_output=True, text=True)
    assert done.returncode == 0 and "inc.rou.xml" in done.stderr, done.stderr
    departed = sorted(t.get("id") for t in ET.parse(trips).getroot().iter("tripinfo"))
    assert ("i1" in departed) == (flaw in ("mismatched", "cut"))
    deps, unrouted = routed_departures(grid.path, [str(main)], until=100.0)
    assert sorted(d.id for d in deps) == departed and unrouted == 0
    assert {d.id: d.type for d in deps}["m"] == "slow"
    assert {p: p.read_bytes() for p in tmp_path.rglob("*.xml") if p != trips} == before


def test_the_estimate_routes_with_the_users_sumo_seed(grid, tmp_path):
    """A probability flow on a routeDistribution: its departures and routes are random draws. The
    estimate's router takes the configuration's seed, as the user's own SUMO run and the rest of the
    fill do (sim.scenario.own_random): with ``<seed value="42"/>`` every vehicle it has en route is on
    the route stock duarouter draws under that seed, and the estimate is not the default seed's; a
    configuration naming SUMO's default seed gives the estimate of one naming none."""
    import subprocess
    import xml.etree.ElementTree as ET

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.amount import _estimate
    from sumo_scendiff.fill.api import FillRequest
    from sumo_scendiff.sim.scenario import SUMO_DEFAULT_SEED, scenario_from_files
    routes = tmp_path / "p.rou.xml"
    routes.write_text('<routes><routeDistribution id="rd"><route id="r0" edges="A0B0 B0C0" probability="0.5"/>'
                      '<route id="r1" edges="A0B0 B0B1" probability="0.5"/></routeDistribution>'
                      '<flow id="p" route="rd" begin="0" end="300" probability="0.25"/></routes>')

    def estimate(seed):
        cfg = tmp_path / f"s{seed}.sumocfg"
        cfg.write_text(f'<configuration><input><net-file value="{grid.path}"/><route-files value="{routes}"/>'
                       '</input>' + (f'<random_number><seed value="{seed}"/></random_number>' if seed else '')
                       + '</configuration>')
        scen = scenario_from_files(config=str(cfg))
        est = _estimate(FillRequest(config=str(cfg)), grid, scen, 60.0, [str(routes)])
        return {v.id: v.edges for v in est.en_route}

    own = estimate(42)
    drawn = tmp_path / "drawn.rou.xml"
    subprocess.run([sumo_binary("duarouter"), "-n", grid.path, "-r", str(routes), "-o", str(drawn), "--seed", "42",
                    "--no-step-log"], check=True, capture_output=True)
    routed = {v.get("id"): tuple(v.find("route").get("edges").split())
              for v in ET.parse(drawn).getroot().iter("vehicle")}
    assert own and all(routed[i][-len(edges):] == edges for i, edges in own.items()), (own, routed)
    assert own != estimate(None)
    assert estimate(SUMO_DEFAULT_SEED) == estimate(None)
