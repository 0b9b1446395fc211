"""Public scenarios' demand that stock SUMO runs (docs/corpus.md): a flow without ``begin`` in an
exported scene, a rerouter interval without ``begin`` in the fill's routing, a route file cut short.
Each on netgenerate's grid, with real SUMO and duarouter."""
from __future__ import annotations

import gzip
import subprocess

import pytest

from sumo_scendiff.core.sumo_xml import elements
from sumo_scendiff.data.demand import DemandError, demand_span, seeding_time


def _edges(grid) -> set[str]:
    return {ln.edge for ln in grid.lanes}


def _sumo(*args) -> subprocess.CompletedProcess:
    from sumo_scendiff.core.tools import sumo_binary
    return subprocess.run([sumo_binary("sumo"), *args, "--no-step-log"], capture_output=True, text=True)


@pytest.mark.parametrize("flow", ['end="50" number="5"',       # the tutorial's: ends before the scene
                                  'number="5" period="10"', 'end="50" period="10"'])
def test_a_flow_without_begin_keeps_the_begin_sumo_gave_it(tmp_path, grid, flow):
    """SUMO gives a flow without begin the simulation's begin; the scene begins later, and its copy
    of the demand writes the begin of the run it was saved from (the user's file stays as it is)."""
    from sumo_scendiff.sim.export import write_sumocfg
    user = tmp_path / "user.rou.xml"
    text = f'<routes>\n    <flow id="f" {flow} from="A0B0" to="B0C0"/>\n</routes>\n'
    user.write_text(text)
    state = tmp_path / "state.xml"
    done = _sumo("-n", grid.path, "-r", str(user), "--end", "101", "--save-state.times", "100",
                 "--save-state.files", str(state))
    assert done.returncode == 0, done.stderr
    folder = tmp_path / "scene"
    folder.mkdir()
    cfg = folder / "scenario.sumocfg"
    write_sumocfg(str(cfg), {"net-file": grid.path, "route-files": str(user), "b": "0"}, str(state), begin=100.0)
    done = _sumo("-c", str(cfg), "--end", "110")
    assert done.returncode == 0, done.stderr
    assert gzip.open(folder / "user.rou.xml.gz").read().decode() == text.replace('<flow id', '<flow begin="0.0" id')
    assert user.read_text() == text


def test_a_rerouter_interval_without_begin_is_not_given_to_the_router(tmp_path, grid):
    """SUMO takes 0 for it; duarouter refuses it, and needs no rerouter to route the demand."""
    from sumo_scendiff.fill.routing import routed_departures
    routes = tmp_path / "d.rou.xml"
    routes.write_text('<routes><flow id="f" begin="0" end="60" period="10" from="A0B0" to="B0C0"/></routes>')
    add = tmp_path / "r.add.xml"
    add.write_text('<additional><rerouter id="rr" edges="A0B0"><interval end="1e3">'
                   '<destProbReroute id="B0C0"/></interval></rerouter></additional>')
    assert _sumo("-n", grid.path, "-r", str(routes), "-a", str(add), "--end", "10").returncode == 0
    departures, unrouted = routed_departures(grid.path, [str(routes)], [str(add)], until=60.0)
    assert [d.id for d in departures] == [f"f.{k}" for k in range(6)] and unrouted == 0
    assert departures[0].edges == ("A0B0", "B0C0")


def _cut_file(tmp_path) -> str:
    """Vehicles every 100 s to 3000 s, the file cut in the middle of the last one (no </routes>)."""
    path = tmp_path / "cut.rou.xml"
    whole = "".join(f'    <vehicle id="v{t}" depart="{t}"><route edges="A0B0 B0C0"/></vehicle>\n'
                    for t in range(0, 3001, 100))
    path.write_text("<routes>\n" + whole + '    <vehicle id="v3100" depart="3100"><route edg')
    return str(path)


def test_a_route_file_cut_short_is_read_to_its_cut_as_sumo_reads_it(tmp_path, grid):
    """Stock SUMO runs it until its reading (route-steps ahead of its clock) reaches the cut; the
    demand reads the same departures, names the cut (file, line, time) and refuses a start after it."""
    path = _cut_file(tmp_path)
    assert _sumo("-n", grid.path, "-r", path, "--end", "600").returncode == 0
    late = _sumo("-n", grid.path, "-r", path, "--end", "3000")
    assert late.returncode != 0 and "cut.rou.xml" in late.stderr
    assert [el.get("id") for _, el in elements([path], ("vehicle",))][-1] == "v3000"
    span = demand_span([path], _edges(grid))
    assert tuple(span) == (0.0, 3000.0)
    assert (span.cut.line, span.cut.read_to, span.cut.stop) == (33, 3000.0, 2800.0)
    assert all(s in span.cut.warning() for s in ("cut.rou.xml", "line 33", "3000 s", "2800 s"))
    assert seeding_time(600.0, None, span, [path]) == 600.0
    with pytest.raises(DemandError, match=r"^--begin 2900 s .* lies after SUMO quits: .*cut\.rou\.xml: cut short at "
                                          r"line 33.*; give an earlier --begin$"):
        seeding_time(2900.0, None, span, [path])
    assert demand_span([path], _edges(grid), route_steps=0).cut.stop == 0.0   # read whole at once


def test_a_route_file_cut_short_travels_with_its_vtypes_read(tmp_path, grid):
    """The scene's readers of the demand (its vTypes) take what SUMO takes of a file cut short."""
    from sumo_scendiff.sim.export import declared_vtypes
    path = tmp_path / "cut.rou.xml"
    path.write_text('<routes><vType id="slow" maxSpeed="5"/><vehicle id="a" depart="0" type="slow">'
                    '<route edges="A0B0"/></vehicle>\n<vehicle id="b"')
    assert list(declared_vtypes([str(path)])) == ["slow"]
    with pytest.raises(DemandError, match="mismatched tag"):      # a flaw that is no cut stays one
        bad = tmp_path / "bad.rou.xml"
        bad.write_text('<routes><vehicle id="a" depart="0"><route edges="A0B0"/></routes>')
        demand_span([str(bad)], _edges(grid))


@pytest.mark.parametrize("how", [(), ("--demand-estimate",)])   # SUMO's own run to --begin; the estimate
def test_a_fill_of_a_flow_without_begin_replays_in_stock_sumo(tmp_path, grid, how):
    """The fill's two starts begin at the fill's time; a flow without begin in their copies keeps
    the begin stock SUMO loads it with, the configuration's (0 here), whenever the fill's own SUMO
    started (the tutorial's 'ends before its begin time' otherwise)."""
    import sys
    user = tmp_path / "user.rou.xml"
    text = ('<routes>\n    <flow id="early" end="50" number="5" from="A0B0" to="B0C0"/>\n'
            '    <flow id="f" number="60" period="4" from="A0B0" to="B0C0"/>\n</routes>\n')
    user.write_text(text)
    out = tmp_path / "filled"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-n", grid.path, "-r", str(user),
                           "--begin", "100", "-o", str(out), *how], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        replay = _sumo("-c", str(out / cfg), "--end", "110")
        assert replay.returncode == 0, (cfg, replay.stderr[-1000:])
    assert user.read_text() == text


def test_the_fill_of_a_route_file_cut_short_warns_and_runs(tmp_path, grid):
    import sys
    out = tmp_path / "filled"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-n", grid.path, "-r", _cut_file(tmp_path),
                           "--begin", "300", "-o", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stderr.count("cut.rou.xml") == 1 and "warning" in done.stderr
    late = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-n", grid.path, "-r", _cut_file(tmp_path),
                           "--begin", "2900", "-o", str(tmp_path / "late")], capture_output=True, text=True)
    assert late.returncode == 2 and "cut.rou.xml" in late.stderr and "Traceback" not in late.stderr
    assert not (tmp_path / "late").exists()


def _including_cut_file(tmp_path) -> str:
    """A route file whose <include> pulls in :func:`_cut_file`, with vehicles of its own after it."""
    path = tmp_path / "main.rou.xml"
    own = "".join(f'    <vehicle id="w{t}" depart="{t}"><route edges="A0B0 B0C0"/></vehicle>\n' for t in (3200, 3300))
    _cut_file(tmp_path)
    path.write_text('<routes>\n    <include href="cut.rou.xml"/>\n' + own + "</routes>\n")
    return str(path)


def test_an_included_file_cut_short_is_reported_and_read_past_as_sumo_reads_it(tmp_path, grid):
    """SUMO's reader of an <include> reports the included file's cut as an error and hands back: the
    including file is read on (its later vehicles depart, SUMO does not quit). The demand reads the same
    departures, names the included file and line, and takes a start after the cut."""
    import xml.etree.ElementTree as ET
    path, trips = _including_cut_file(tmp_path), tmp_path / "trips.xml"
    done = _sumo("-n", grid.path, "-r", path, "--end", "3400", "--tripinfo-output", str(trips))
    assert done.returncode == 0 and "cut.rou.xml" in done.stderr, done.stderr
    departed = [t.get("id") for t in ET.parse(trips).getroot().iter("tripinfo")]
    assert departed == [el.get("id") for _, el in elements([path], ("vehicle",))]
    assert departed[-3:] == ["v3000", "w3200", "w3300"]
    span = demand_span([path], _edges(grid))
    assert tuple(span) == (0.0, 3300.0)
    assert (span.cut.line, span.cut.read_to, span.cut.stop) == (33, 3000.0, float("inf"))
    assert span.cut.path.endswith("cut.rou.xml") and span.cut.included_from.endswith("main.rou.xml")
    assert all(s in span.cut.warning() for s in ("cut.rou.xml", "line 33", "included from", "main.rou.xml"))
    assert seeding_time(3250.0, None, span, [path]) == 3250.0


def test_the_fill_of_an_included_file_cut_short_warns_once_and_runs_past_it(tmp_path, grid):
    """A start after the cut's time (where SUMO would quit, were the cut in the file it was given) runs."""
    import sys
    out = tmp_path / "filled"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-n", grid.path, "-r",
                           _including_cut_file(tmp_path), "--begin", "3250", "-o", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stderr.count("cut.rou.xml: cut short at line 33") == 1 and "included from" in done.stderr


def test_a_vehicle_departing_at_begin_does_not_depart_again_in_a_scene(tmp_path, grid):
    """depart="begin" is the simulation's begin: the scene's copy writes the begin SUMO loaded the demand
    with, so the vehicle (long arrived, or in the state) does not depart a second time at the scene's."""
    from sumo_scendiff.sim.export import write_sumocfg
    user = tmp_path / "user.rou.xml"
    text = ('<routes>\n    <vehicle id="b" depart="begin"><route edges="A0B0 B0C0"/></vehicle>\n'
            "    <trip id='t' depart='begin' from='A0B0' to='B0C0'/>\n"
            '    <vehicle id="late" depart="150"><route edges="A0B0 B0C0"/></vehicle>\n</routes>\n')
    user.write_text(text)
    state = tmp_path / "state.xml"
    assert _sumo("-n", grid.path, "-r", str(user), "--end", "101", "--save-state.times", "100",
                 "--save-state.files", str(state)).returncode == 0
    folder = tmp_path / "scene"
    folder.mkdir()
    cfg = folder / "scenario.sumocfg"
    write_sumocfg(str(cfg), {"net-file": grid.path, "route-files": str(user), "b": "0"}, str(state), begin=100.0)
    trips = tmp_path / "trips.xml"
    done = _sumo("-c", str(cfg), "--end", "300", "--tripinfo-output", str(trips))
    assert done.returncode == 0, done.stderr
    assert [el.get("id") for _, el in elements([str(trips)], ("tripinfo",))] == ["late"]   # b and t drove before
    copy = gzip.open(folder / "user.rou.xml.gz").read().decode()
    assert copy == text.replace('depart="begin"', 'depart="0.0"').replace("depart='begin'", "depart='0.0'")
    assert user.read_text() == text


FLAWS = {"missing": None, "empty": "",
         "mismatched": ('<routes>\n    <vehicle id="i1" depart="1"><route edges="A0B0 B0C0"/></vehicle>\n'
                        '    <vehicle id="i2" depart="2"><route edges="A0B0 B0C0"/></vehicl>\n</routes>\n')}
FLAW_WORDS = {"missing": "no such file", "empty": "empty file", "mismatched": "mismatched tag"}


@pytest.mark.parametrize("flaw", list(FLAWS))
def test_an_included_route_files_other_flaws_are_reported_and_read_past_as_sumo_reads_them(tmp_path, grid, flaw):
    """SUMO reports an included route file that is missing, empty or not well-formed (its elements whole
    before the flaw are loaded) and reads on past the include: the demand reads the same vehicles, warns
    naming the file and its flaw, and a scene's folder of it replays in stock SUMO."""
    import xml.etree.ElementTree as ET

    from sumo_scendiff.sim.export import write_sumocfg
    if FLAWS[flaw] is not None:
        (tmp_path / "inc.rou.xml").write_text(FLAWS[flaw])
    path, trips = tmp_path / "main.rou.xml", tmp_path / "trips.xml"
    path.write_text('<routes>\n    <vehicle id="a" depart="0"><route edges="A0B0 B0C0"/></vehicle>\n'
                    '    <include href="inc.rou.xml"/>\n'
                    '    <vehicle id="b" depart="5"><route edges="A0B0 B0C0"/></vehicle>\n</routes>\n')
    done = _sumo("-n", grid.path, "-r", str(path), "--end", "100", "--tripinfo-output", str(trips))
    assert done.returncode == 0 and "inc.rou.xml" in done.stderr, done.stderr
    departed = sorted(t.get("id") for t in ET.parse(trips).getroot().iter("tripinfo"))
    assert departed == sorted(el.get("id") for _, el in elements([str(path)], ("vehicle",)))
    span = demand_span([str(path)], _edges(grid))
    assert tuple(span) == (0.0, 5.0) and span.cut.stop == float("inf")
    assert all(s in span.cut.warning() for s in ("inc.rou.xml", FLAW_WORDS[flaw], "included from", "main.rou.xml"))
    folder = tmp_path / "scene"
    folder.mkdir()
    write_sumocfg(str(folder / "scenario.sumocfg"), {"net-file": grid.path, "route-files": str(path)}, None,
                  begin=0.0)
    replay = _sumo("-c", str(folder / "scenario.sumocfg"), "--end", "20")
    assert replay.returncode == 0, replay.stderr
