"""No single vehicle sinks a fill: a bus line's stops behind a seeded bus are dropped (it keeps those
ahead), a vehicle SUMO refuses when loading the folder is taken out alone with SUMO's reason, and
SUMO's and duarouter's repeated warnings are one line each. Real SUMO, real model, a tiny grid."""
from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest

# the bus line: one stop per edge, 40-60 m along it, on edges of this length or longer
LINE = ["A0A1", "A1A2", "A2A3", "A3B3", "B3C3", "C3D3"]
STOP_END = 60.0
BEGIN = 300


def _netgenerate(out: str, *extra: str) -> str:
    from sumo_scendiff.core.tools import sumo_binary
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "4", "--grid.length", "150",
                    "--default.lanenumber", "1", "-o", out, *extra], check=True, capture_output=True)
    return out


@pytest.fixture(scope="module")
def bus_fill(tmp_path_factory):
    """``fill -c bus.sumocfg --begin 300``: a bus every 20 s along LINE, stopping 15 s at each stop,
    and a car flow; at 300 s buses stand between their stops, some past one on the same edge."""
    d = tmp_path_factory.mktemp("bus")
    _netgenerate(str(d / "grid.net.xml"))
    stops = "".join(f'<busStop id="s{k}" lane="{e}_0" startPos="40" endPos="{STOP_END:g}"/>' for k, e in enumerate(LINE))
    (d / "stops.add.xml").write_text(f"<additional>{stops}</additional>")
    calls = "".join(f'<stop busStop="s{k}" duration="15"/>' for k in range(len(LINE)))
    (d / "bus.rou.xml").write_text(
        f'<routes><vType id="bus" vClass="bus"/><route id="line1" edges="{" ".join(LINE)}"/>'
        f'<flow id="L1" type="bus" route="line1" line="1" begin="0" end="900" period="20">{calls}</flow>'
        '<flow id="cars" begin="0" end="900" period="6" from="D0D1" to="A3A2"/></routes>')
    (d / "bus.sumocfg").write_text(
        '<configuration><input><net-file value="grid.net.xml"/><route-files value="bus.rou.xml"/>'
        '<additional-files value="stops.add.xml"/></input><time><begin value="0"/><end value="900"/></time>'
        '</configuration>')
    from sumo_scendiff.fill.__main__ import get_options, main
    out = d / "o"
    assert main(get_options(["-c", str(d / "bus.sumocfg"), "--begin", str(BEGIN), "--demand-estimate",
                                    "-o", str(out)])) == 0
    with open(out / "fill.json") as f:
        return d, json.load(f)


def _expected_stops(edge: str, pos: float) -> list[str]:
    """The stops of LINE still ahead of a bus at ``pos`` on ``edge``."""
    k = LINE.index(edge)
    return [f"s{j}" for j in range(k, len(LINE)) if j > k or pos <= STOP_END]


def _run(cfg, until: float) -> subprocess.CompletedProcess:
    from sumo_scendiff.core.tools import sumo_binary
    return subprocess.run([sumo_binary(), "-c", str(cfg), "--end", f"{until:g}", "--no-step-log", "true"],
                          check=False, capture_output=True, text=True, timeout=120)


@pytest.mark.slow
def test_a_bus_past_a_stop_keeps_only_the_stops_ahead(bus_fill):
    """The fill completes; each seeded bus of the line has exactly the stops ahead of it in the saved
    state (one past its stop on the same edge has dropped it), and both starts run in stock SUMO."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    d, doc = bus_fill
    buses = [a["vehicle"] for a in doc["agents"] if a.get("demand", {}).get("id", "").startswith("L1.") and a["vehicle"]]
    assert buses and doc["summary"]["refused"] == 0
    libsumo.start([sumo_binary(), "-c", str(d / "o" / "scenario.sumocfg"), "--no-step-log", "true"])
    try:
        seen = {v: (libsumo.vehicle.getRoadID(v), libsumo.vehicle.getLanePosition(v),
                    [s.stoppingPlaceID for s in libsumo.vehicle.getStops(v)]) for v in buses}
    finally:
        libsumo.close()
    on_line = {v: s for v, s in seen.items() if s[0] in LINE}
    assert on_line
    # the case that sank the fill: a bus past its stop on the edge it stands on
    assert any(pos > STOP_END for _, pos, _ in on_line.values())
    for v, (edge, pos, stops) in on_line.items():
        assert stops == _expected_stops(edge, pos), (v, edge, pos, stops)
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        run = _run(d / "o" / cfg, BEGIN + 120)
        assert run.returncode == 0 and "Error" not in run.stderr, run.stderr


@pytest.mark.slow
def test_a_vehicle_sumo_refuses_at_loading_is_taken_out_alone(bus_fill, tmp_path):
    """A portable start with one vehicle on a route it cannot drive (SUMO quits at its insertion):
    that vehicle alone is taken out of both starts with SUMO's reason, the rest load and run."""
    from sumo_scendiff.fill.seed import admit_start, refuse_at_load
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.stops import place_ends
    d, doc = bus_fill
    folder = tmp_path / "o"
    shutil.copytree(d / "o", folder)
    seeded = [a for a in doc["agents"] if a["vehicle"]]
    victim = seeded[0]["vehicle"]
    routes = folder / "start.rou.xml"
    text = routes.read_text()
    cut = f'<route id="{victim}_replay" edges="'
    assert cut in text
    routes.write_text(text.replace(cut, cut + "A0A1 C3D3 ", 1))     # not connected
    poses = {a["vehicle"]: (a["x"], a["y"]) for a in seeded}
    _, refused = admit_start(str(folder), poses, place_ends([str(d / "stops.add.xml")], Network.load(str(d / "grid.net.xml"))))
    assert list(refused) == [victim] and "no valid route" in refused[victim] and victim in refused[victim]
    agents = [dict(a) for a in doc["agents"]]
    refuse_at_load(agents, refused)
    mine = next(a for a in agents if a["x"] == seeded[0]["x"] and a["y"] == seeded[0]["y"])
    assert mine["status"] == "refused" and mine["vehicle"] is None and "no valid route" in mine["reason"]
    assert sum(a["status"] == "refused" for a in agents) == 1
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        run = _run(folder / cfg, BEGIN + 60)
        assert run.returncode == 0 and "Error" not in run.stderr, run.stderr
    import gzip
    with gzip.open(folder / "state.xml.gz", "rt") as f:
        assert f'id="{victim}"' not in f.read()


def test_repeated_warnings_are_one_line_each():
    from sumo_scendiff.core.sumo_log import summarise
    lines = [f"Warning: No connection between edge 'e{i}' and edge 'f{i}' found." for i in range(1475)]
    lines += ["Warning: Vehicle 'x' has no valid route.", "",
              "Warning: Teleporting vehicle 'a'; waited too long (jam), lane='l_0', time=12.00.",
              "Warning: Teleporting vehicle 'b'; waited too long (jam), lane='m_1', time=340.50."]
    out = summarise(lines)
    assert out == ["Warning: No connection between edge '…' and edge '…' found. (1 475 times, first: "
                   "No connection between edge 'e0' and edge 'f0' found.)",
                   "Warning: Vehicle 'x' has no valid route.",
                   "Warning: Teleporting vehicle '…'; waited too long (jam), lane='…', time=#. (2 times, first: "
                   "Teleporting vehicle 'a'; waited too long (jam), lane='l_0', time=12.00.)"]


def test_duarouter_warnings_are_counted(tmp_path, capsys):
    """Trips to an edge nothing leads to: duarouter cannot route them and says so once, with the count."""
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.routing import routed_departures
    net = _netgenerate(str(tmp_path / "grid.net.xml"))
    # A0 is a corner: without its two incoming edges nothing reaches A0B0
    cut = str(tmp_path / "cut.net.xml")
    subprocess.run([sumo_binary("netconvert"), "-s", net, "--remove-edges.explicit", "B0A0,A1A0", "-o", cut],
                   check=True, capture_output=True)
    trips = "".join(f'<trip id="t{i}" depart="{i}" from="D3C3" to="A0B0"/>' for i in range(30))
    (tmp_path / "t.rou.xml").write_text(f'<routes><trip id="ok" depart="0" from="D3C3" to="C3B3"/>{trips}</routes>')
    departures, unrouted = routed_departures(cut, [str(tmp_path / "t.rou.xml")])
    assert [d.id for d in departures] == ["ok"] and unrouted == 30
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("duarouter:")]
    assert any(ln.startswith("duarouter: Warning: No connection between edge '…' and edge '…'") and "(30 times" in ln
               for ln in err), err
    # that, "has no valid route" and "not reachable": a line each for 30 trips' 90 warnings
    assert len(err) == 3 and all("times, first:" in ln for ln in err), err


def test_the_estimate_goes_on_under_the_users_sumo_seed(bus_fill):
    """The folder's configuration runs the user's scenario on from the estimate under its own SUMO seed
    (the configuration names none: SUMO's default), not the fill's -s (the model's draws)."""
    import xml.etree.ElementTree as ET
    d, doc = bus_fill
    kept = {el.tag: el.get("value") for el in ET.parse(d / "o" / "scenario.sumocfg").getroot().iter()}
    assert kept["seed"] == "23423" and doc["seed"] == 0


def test_a_flawed_include_is_said_once(tmp_path, capfd, monkeypatch):
    """A route file including a missing file: SUMO reads past it with an error line at every load, and
    the fill loads it several times (SUMO's run to T, the start from its state, the folder's two
    starts, their copies of the file naming the folder's path): the fill warns once naming the file,
    SUMO's line is shown once, and the folder is written."""
    from sumo_scendiff.fill.__main__ import get_options, main
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))     # SUMO's run to T made here
    _netgenerate(str(tmp_path / "grid.net.xml"))
    (tmp_path / "main.rou.xml").write_text(
        '<routes>\n    <flow id="f" begin="0" end="200" period="5" from="A0A1" to="A2A3"/>\n'
        '    <include href="gone.rou.xml"/>\n</routes>\n')
    (tmp_path / "s.sumocfg").write_text('<configuration><input><net-file value="grid.net.xml"/>'
                                        '<route-files value="main.rou.xml"/></input></configuration>')
    capfd.readouterr()
    assert main(get_options(["-c", str(tmp_path / "s.sumocfg"), "--begin", "30", "-o", str(tmp_path / "o")])) == 0
    err = capfd.readouterr().err.splitlines()
    assert sum("gone.rou.xml: no such file" in ln for ln in err) == 1, err
    assert sum("Cannot read file" in ln for ln in err) == 1, err
    assert (tmp_path / "o" / "state.xml.gz").exists()
