"""SUMO's inputs read as SUMO reads them (core.sumo_xml, data.demand) and judged by SUMO itself
before any expensive work (sim.preflight): any root element, gzip, includes, flows, persons and
containers, public transport, calibrators, rerouters, TAZ; SUMO's own refusals in one line."""
from __future__ import annotations

import gzip
import os
import subprocess
import sys

import pytest

from sumo_scendiff.core.sumo_xml import elements, seconds
from sumo_scendiff.data.demand import DemandError, demand_span
from sumo_scendiff.sim.preflight import preflight
from sumo_scendiff.sim.scenario import ScenarioError, scenario_from_files

# an additional file as many published scenarios write it: root <add>, vTypes, public transport
# stops, a TAZ, a calibrator and a rerouter, a detector and a timed event writing outputs
ADD = ('<add>\n  <vTypeDistribution id="mix">\n    <vType id="small" length="4" probability="0.7"/>\n'
       '    <vType id="van" vClass="delivery" length="6.5" probability="0.3"/>\n  </vTypeDistribution>\n'
       '  <vType id="bus" vClass="bus"/>\n'
       '  <busStop id="bs1" lane="A0B0_0" startPos="20" endPos="45" lines="1"/>\n'
       '  <busStop id="bs2" lane="B0C0_0" startPos="40" endPos="65" lines="1"/>\n'
       '  <taz id="t1" edges="A0B0 A1B1"/>\n'
       '  <calibrator id="cal" edge="A2B2" pos="10" output="out/cal.xml"/>\n'
       '  <rerouter id="rr" edges="A1B1"><interval begin="0" end="30000"><closingReroute id="B1C1"/>'
       '</interval></rerouter>\n'
       '  <inductionLoop id="e1" lane="A0B0_0" pos="80" period="60" file="out/e1.xml"/>\n'
       '  <timedEvent type="SaveTLSStates" dest="out/tls.xml"/>\n</add>\n')
# demand of every kind, times as seconds and clock time, from 7:00:00 (25200 s) to 7:10:00
ROUTES = ('<routes>\n'
          '  <route id="line1" edges="A0B0 B0C0"/>\n'
          '  <flow id="bus" type="bus" line="1" route="line1" begin="7:00:00" end="7:10:00" period="120">\n'
          '    <stop busStop="bs1" duration="20"/>\n    <stop busStop="bs2" duration="10"/>\n  </flow>\n'
          '  <vehicle id="v0" type="mix" depart="25220"><route edges="A1B1 B1C1"/>'
          '<stop lane="B1C1_0" endPos="60" duration="5" until="7:01:00"/></vehicle>\n'
          '  <flow id="fh" type="mix" begin="7:00:30" vehsPerHour="360" number="5" from="A2B2" to="B2C2"/>\n'
          '  <flow id="fp" begin="25200" end="7:05:00" probability="0.05" from="A0A1" to="A1A2"/>\n'
          '  <person id="p0" depart="25210"><walk edges="A0B0 B0C0"/><stop lane="B0C0_0" endPos="30" '
          'duration="20"/></person>\n'
          '  <personFlow id="pf" begin="7:00:00" end="25800" period="120"><walk from="A1B1" to="B1C1"/>'
          '</personFlow>\n'
          '  <container id="c0" depart="25300"><tranship edges="A2B2 B2C2"/></container>\n'
          '  <containerFlow id="cf" begin="25200" number="3" period="100"><tranship edges="B0C0 C0C1"/>'
          '</containerFlow>\n</routes>\n')


def _write(path, text: str, gz: bool = False):
    path.parent.mkdir(parents=True, exist_ok=True)
    if gz:
        with gzip.open(path, "wt") as f:
            f.write(text)
    else:
        path.write_text(text)
    return str(path)


def _config(folder, net: str, routes: str, additional: str, extra: str = "") -> str:
    return _write(folder / "run.sumocfg",
                  f'<configuration><input><net-file value="{net}"/><route-files value="{routes}"/>'
                  f'<additional-files value="{additional}"/></input><time><begin value="7:00:00"/></time>'
                  f'{extra}</configuration>')


@pytest.fixture
def user(tmp_path, grid):
    """A user's scenario folder: the grid, an <add> additional file, every kind of demand."""
    d = tmp_path / "user"
    (d / "out").mkdir(parents=True)
    _write(d / "city.add.xml", ADD)
    _write(d / "city.rou.xml", ROUTES)
    _config(d, grid.path, "city.rou.xml", "city.add.xml",
            '<output><tripinfo-output value="out/trips.xml"/><summary value="out/summary.xml"/></output>'
            '<report><log value="out/log.txt"/></report>')
    return d


def _edges(grid) -> set[str]:
    return {ln.edge for ln in grid.lanes}


def test_every_kind_of_input_sumo_reads_is_read(user, grid):
    """An <add>-rooted additional file (vTypes, bus stops, TAZ, calibrator, rerouter), flows by
    period, rate, number and probability with clock times, persons and containers with their
    plans, stops with until and duration: read, the demand's span as SUMO departs it, and stock
    SUMO loads it all without writing anything beside the user's files."""
    scen = scenario_from_files(str(user / "run.sumocfg"))
    assert scen.additional == (str(user / "city.add.xml"),) and scen.begin == 25200.0
    # the bus line and the person flow depart until 7:10:00; the rate flow's 5th at 7:01:10
    assert demand_span(scen.routes, _edges(grid), scen.additional, begin=scen.begin) == (25200.0, 25800.0)
    before = sorted(os.listdir(user / "out"))
    assert preflight(scen) is scen
    assert sorted(os.listdir(user / "out")) == before == []


def test_a_gzipped_route_file_whatever_its_name(tmp_path, grid):
    """SUMO reads a gzipped file by its bytes: with or without .gz in its name."""
    for name in ("d.rou.xml.gz", "hidden.rou.xml"):
        path = _write(tmp_path / name, ROUTES, gz=True)
        assert demand_span([path], _edges(grid), [_write(tmp_path / "a.add.xml", ADD)]) == (25200.0, 25800.0)
        preflight(scenario_from_files(net=grid.path, routes=[path], additional=[str(tmp_path / "a.add.xml")]))


def test_includes_are_read_in_place_relative_to_the_including_file(tmp_path, grid):
    """<include href> in a route and an additional file, resolved from the including file's folder
    as SUMO resolves it. An additional file including a missing file is one SUMO refuses at load (the
    preflight names it with SUMO's error); the reading notes it and reads past, as SUMO reads a route file."""
    _write(tmp_path / "parts" / "types.xml", '<additional><vType id="mix"/><vType id="bus"/></additional>')
    add = _write(tmp_path / "parts" / "main.add.xml",
                 '<add><include href="types.xml"/><busStop id="bs1" lane="A0B0_0" startPos="20" endPos="45"/>'
                 '<busStop id="bs2" lane="B0C0_0" startPos="40" endPos="65"/></add>')
    _write(tmp_path / "more" / "late.rou.xml", '<routes><vehicle id="late" type="mix" depart="9:00:00">'
           '<route edges="A0B0"/></vehicle></routes>')
    routes = _write(tmp_path / "d.rou.xml", ROUTES.replace("</routes>", '<include href="more/late.rou.xml"/>'
                                                           '</routes>'))
    tags = [el.tag for _, el in elements([add], {"vType", "busStop"})]
    assert tags == ["vType", "vType", "busStop", "busStop"]
    assert demand_span([routes], _edges(grid), [add]) == (25200.0, 32400.0)
    preflight(scenario_from_files(net=grid.path, routes=[routes], additional=[add]))
    bad = _write(tmp_path / "bad.add.xml", '<add><include href="parts/nothere.xml"/></add>')
    cuts = []
    assert list(elements([bad], {"vType"}, cuts)) == []
    assert (cuts[0].path, cuts[0].included_from, cuts[0].problem) == (
        str(tmp_path / "parts" / "nothere.xml"), bad, "no such file")
    with pytest.raises(ScenarioError, match=r"SUMO refuses to load it: .*parts/nothere\.xml"):
        preflight(scenario_from_files(net=grid.path, routes=[routes], additional=[bad]))


def test_flow_spans_as_sumo_computes_them(tmp_path, grid):
    """A flow departs from its begin (default: the simulation's) to its end, or for `number`
    vehicles at its period or rate, or until the simulation's end, or for a day."""
    def span(flow: str, **kw):
        f = _write(tmp_path / "f.rou.xml", f'<routes><flow id="f" from="A0B0" to="B0C0" {flow}/></routes>')
        return demand_span([f], _edges(grid), **kw)
    assert span('begin="1:00:00" number="4" period="30"') == (3600.0, 3690.0)
    assert span('begin="100" number="3" vehsPerHour="720"') == (100.0, 110.0)
    assert span('begin="0" number="11" period="exp(0.5)"') == (0.0, 20.0)      # on average every 2 s
    assert span('end="600" number="10"', begin=60.0) == (60.0, 600.0)
    assert span('begin="0:02:00" period="10"', end=900.0) == (120.0, 900.0)
    assert span('begin="0:02:00" probability="0.1"') == (120.0, 120.0 + 86400.0)
    assert seconds("1:00:00:00") == 86400.0 and seconds("0:10") is None and seconds("triggered") is None


def test_a_route_file_with_a_syntax_error_is_one_line_naming_it(tmp_path, grid):
    """Named by the reader, and by SUMO (which reads route files at its first step: the
    configuration's own TraCI port and clients do not keep the preflight from getting there)."""
    bad = _write(tmp_path / "bad.rou.xml", '<routes>\n<vehicle id="a" depart="0">\n<route edges="A0B0"/>\n'
                 '</routes>\n')
    with pytest.raises(DemandError, match=r"^.*bad\.rou\.xml: not well-formed XML \(mismatched tag: line 4") as e:
        demand_span([bad], _edges(grid))
    assert "\n" not in str(e.value)
    cfg = _write(tmp_path / "t.sumocfg", f'<configuration><net-file value="{grid.path}"/><route-files '
                 'value="bad.rou.xml"/><traci_server><remote-port value="1"/><num-clients value="3"/>'
                 '</traci_server></configuration>')
    with pytest.raises(ScenarioError, match=r"^.*bad\.rou\.xml: line \d+, column \d+: SUMO refuses it: "
                       r"expected end of tag 'vehicle'$"):
        preflight(scenario_from_files(cfg), timeout=120)


def test_a_scenario_sumo_is_slow_to_load_is_not_judged(user):
    """Past the preflight's time SUMO is stopped and the scenario goes on (the run's own SUMO
    speaks for it then)."""
    scen = scenario_from_files(str(user / "run.sumocfg"))
    assert preflight(scen, timeout=0.0) is scen
    assert sorted(os.listdir(user / "out")) == []


def test_a_demand_for_another_network_is_named_as_sumo_names_it(tmp_path, grid):
    foreign = _write(tmp_path / "foreign.rou.xml", '<routes><vehicle id="a" depart="0">'
                     '<route edges="nowhere gone"/></vehicle></routes>')
    with pytest.raises(ScenarioError) as e:
        preflight(scenario_from_files(net=grid.path, routes=[foreign]))
    assert "foreign.rou.xml" in str(e.value) and "\n" not in str(e.value)
    assert str(e.value).endswith("SUMO refuses to load it: The edge 'nowhere' within the route for vehicle "
                                 "'a' is not known. The route can not be build.")
    with pytest.raises(DemandError, match="foreign.rou.xml: does not match the network"):
        demand_span([foreign], _edges(grid))


def test_an_error_in_a_quieted_file_names_the_users_file(user, grid):
    """SUMO loads a copy of an additional file whose outputs are quieted: its error names the
    user's file, not the copy."""
    bad = _write(user / "bad.add.xml", ADD.replace('lane="B0C0_0"', 'lane="B0C0_7"'))
    with pytest.raises(ScenarioError) as e:
        preflight(scenario_from_files(str(user / "run.sumocfg"), additional=[bad]))
    assert "B0C0_7" in str(e.value) and "scendiff-additional" not in str(e.value)


@pytest.mark.slow    # the CLI imports the model's libraries before it reads the scenario
def test_a_configuration_sumo_refuses_stops_the_cli_in_one_line(user, grid, tmp_path):
    """`run -c` on a configuration stock SUMO refuses: exit 2, SUMO's error in one line, nothing
    written (the real CLI, in its own process)."""
    _write(user / "other.rou.xml", '<routes><vehicle id="w" depart="7:00:00"><route edges="nowhere"/>'
           '</vehicle></routes>')
    cfg = _config(user, grid.path, "other.rou.xml", "city.add.xml")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-c", cfg, "-o", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert "run.sumocfg: SUMO refuses to load it: The edge 'nowhere' within the route for vehicle 'w'" in done.stderr
    assert not out.exists() and sorted(os.listdir(user / "out")) == []


def _game_configs() -> list[str]:
    import glob

    from sumo_scendiff.core.tools import sumo_tool
    return sorted(glob.glob(sumo_tool("game", "*.sumocfg")))


@pytest.mark.slow    # SUMO's own public scenarios, shipped with the wheel: seconds each
@pytest.mark.parametrize("config", _game_configs(), ids=os.path.basename)
def test_sumos_own_scenarios_are_read(config):
    """Each of SUMO's game scenarios (trams and trains with persons and containers, DRT, bus
    lines, <add>, <tlLogics> and GUI settings as additional files, flows of every kind) is read
    and loaded by stock SUMO; one that needs an option only an OSG-enabled sumo-gui has is
    refused in SUMO's words."""
    import sumolib
    scen = scenario_from_files(config)
    net = sumolib.net.readNet(scen.net, withInternal=True)
    edges = {e.getID() for e in net.getEdges(withInternal=True)}
    if scen.routes:
        first, last = demand_span(scen.routes, edges, scen.additional, begin=scen.begin, end=scen.end)
        assert 0 <= first <= last
    try:
        preflight(scen)
    except ScenarioError as e:
        assert "No option with the name 'osg-view' exists" in str(e) and "\n" not in str(e)


_BEFORE_TORCH = """import runpy, sys
sys.argv = sys.argv[1:]
try:
    runpy.run_module(sys.argv[0], run_name="__main__")
except SystemExit as e:
    print(e.code, "torch" in sys.modules)
"""


@pytest.mark.parametrize("module", ["sumo_scendiff.run", "sumo_scendiff.fill"])
def test_a_scenario_sumo_refuses_is_answered_before_the_model_is_imported(module, tmp_path):
    """run and fill: a missing file and a configuration stock SUMO refuses are one line and exit 2,
    answered before torch is imported (seconds, not the model's load)."""
    import shutil
    here = os.path.join(os.path.dirname(__file__), "data", "corpus", "game_square")
    shutil.copytree(here, tmp_path / "sq")
    cfg = tmp_path / "sq" / "square.sumocfg"
    cfg.write_text(cfg.read_text().replace("<report>", '<report>\n        <osg-view value="true"/>'))
    for config, words in ((cfg, "No option with the name 'osg-view' exists"), (tmp_path / "no.sumocfg", "no such file")):
        p = subprocess.run([sys.executable, "-c", _BEFORE_TORCH, module, "-c", str(config), "-o", str(tmp_path / "o")],
                           capture_output=True, text=True, timeout=120)
        assert p.stdout.split() == ["2", "False"], p.stdout + p.stderr[-500:]
        assert p.stderr.count("\n") == 1 and words in p.stderr and str(config) in p.stderr, p.stderr
        assert not (tmp_path / "o").exists()


def test_a_scenario_without_a_car_lane_ends_with_nothing_generated(tmp_path):
    """SUMO's railway game (trains, stops, rerouters): stock SUMO runs it, so run -c and fill -c end
    with exit 0 and one notice, run.json / fill.json saying why and nothing that looks like a scene
    or a filled start; the bare network with -n stays an error."""
    import json
    cfg = os.path.join(os.path.dirname(__file__), "data", "corpus", "game_rail", "rail.sumocfg")
    for module, out, record in (("run", tmp_path / "r", "run.json"), ("fill", tmp_path / "f", "fill.json")):
        p = subprocess.run([sys.executable, "-m", f"sumo_scendiff.{module}", "-c", cfg, "--begin", "120",
                            "-o", str(out)], capture_output=True, text=True, timeout=300)
        assert p.returncode == 0 and p.stdout.count("\n") == 1 and "nothing to generate: no car lane" in p.stdout, \
            p.stdout + p.stderr[-500:]
        assert os.listdir(out) == [record]
        doc = json.loads((out / record).read_text())
        assert "no lane a passenger car may use" in doc["nothing_to_generate"]
        assert doc["scenes" if module == "run" else "agents"] == []
    p = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-n",
                        os.path.join(os.path.dirname(cfg), "rail", "net.net.xml"), "-o", str(tmp_path / "n")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "no lane a passenger car may use" in p.stderr


def test_the_fleet_stops_and_programs_are_read_through_includes_and_gzip(tmp_path, grid):
    """The readers of vTypes and their distributions (sim/fleet.py, fill/vtypes.py,
    fill/en_route.py), of stopping places (sim/stops.py), of signal programs (fill/programs.py) and
    of the network's head (map/network.py) read through <include> and a gzipped file without .gz in
    its name, as SUMO does."""
    import shutil

    from sumo_scendiff.fill.en_route import write_vtypes
    from sumo_scendiff.fill.programs import signal_programs
    from sumo_scendiff.fill.vtypes import vtype_table
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.fleet import file_mix, vtype_distributions
    from sumo_scendiff.sim.stops import place_ends, stopping_places
    _write(tmp_path / "parts" / "inner.xml", ADD.replace("<add>", "<additional>").replace("</add>", "</additional>")
           + "", gz=True)
    add = _write(tmp_path / "main.add.xml", '<add><include href="parts/inner.xml"/>'
                 '<tlLogic id="B1" type="static" programID="x" offset="0:00:10"><phase duration="0:00:30" state="G"/>'
                 '<phase duration="5" state="y"/></tlLogic></add>')
    _write(tmp_path / "parts" / "r.xml", ROUTES, gz=True)
    routes = _write(tmp_path / "d.rou.xml", '<routes><include href="parts/r.xml"/></routes>')
    dists = vtype_distributions([add])
    assert dists == {"mix": pytest.approx({"small": 0.7, "van": 0.3})}
    mix = file_mix([routes], dists)
    assert mix["small"] > 0 and mix["van"] > 0 and mix["bus"] > 0
    assert vtype_table([add], lambda el: el.get("vClass") or "passenger") == \
        {"small": "passenger", "van": "delivery", "bus": "bus", "mix": "passenger"}
    assert sorted(write_vtypes([add], str(tmp_path / "types.add.xml"))) == ["bus", "mix"]
    assert stopping_places([add]) == {"bs1": "A0B0_0", "bs2": "B0C0_0"}
    assert place_ends([add], grid) == {"bs1": ("A0B0", 45.0), "bs2": ("B0C0", 65.0)}
    program = signal_programs([add])["B1"]
    assert program.phases == ((30.0, "G"), (5.0, "y")) and program.offset == 10.0
    hidden = tmp_path / "hidden.net.xml"          # gzipped, its name without .gz
    with open(grid.path, "rb") as f, gzip.open(hidden, "wb") as g:
        shutil.copyfileobj(f if not grid.path.endswith(".gz") else gzip.open(grid.path), g)
    assert len(Network.load(str(hidden)).lanes) == len(grid.lanes)
