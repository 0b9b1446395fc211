"""fill with a demand: SUMO's own run to --begin written as the fill's folder (fill/warm_start.py)."""
from __future__ import annotations

import json
import os
import subprocess

import pytest

from .test_warmup import DEMAND


@pytest.fixture()
def scenario(cross_net, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))     # the saved states go here
    routes = tmp_path / "demand.rou.xml"
    # and vehicles of SUMO's own DEFAULT_VEHTYPE, which the portable start may not define again
    routes.write_text(DEMAND.replace('  <vehicle id="late"', '  <flow id="f_default" begin="0" end="400" '
                                     'period="15"><route edges="ec cw"/></flow>\n  <vehicle id="late"'))
    return cross_net, str(routes)


def _sumos_own(net: str, routes: str | None, until: float, additional: tuple[str, ...] = ()) -> set[str]:
    """The vehicles stock SUMO has on the network at ``until`` (libsumo, one step at a time, SUMO's
    default seed)."""
    from sumo_scendiff.sim.scenario import SUMO_DEFAULT_SEED
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    sim = start(SimConfig(net=net, routes=(routes,) if routes else (), additional=additional, step_length=1.0,
                          begin=0.0, seeding_options=False, seed=SUMO_DEFAULT_SEED))
    try:
        while sim.simulation.getTime() < until - 1e-9:
            sim.simulationStep()
        return set(sim.vehicle.getIDList())
    finally:
        close(sim)


def test_the_start_is_sumos_own_run(scenario, tmp_path):
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.api import fill
    from sumo_scendiff.fill.warm_start import PORTABLE_PREFIX
    net, routes = scenario
    done = fill(net, routes=(routes,), begin=200.0, out=str(tmp_path / "filled"), step_length=1.0)
    doc = done.doc
    assert doc["density"]["start"] == "sumo" and doc["state_time"] == 200.0
    own = _sumos_own(net, routes, 200.0)
    assert {a["vehicle"] for a in doc["agents"]} == own and len(own) > 3
    assert any(v.startswith("f_default") for v in own)
    assert doc["summary"]["vehicles"] == len(own) and doc["summary"]["refused"] == 0
    assert os.listdir(tmp_path / "cache" / "sumo-scendiff" / "states")     # kept for the next time
    for cfg in ("scenario.sumocfg", "start.sumocfg"):    # both starts run in stock SUMO
        run = subprocess.run([sumo_binary(), "-c", os.path.join(done.folder, cfg), "--end", "230",
                              "--no-step-log", "true"], capture_output=True, text=True)
        assert run.returncode == 0, run.stderr[-400:]
    with open(os.path.join(done.folder, "start.rou.xml")) as f:
        text = f.read()
    assert text.count("<vehicle ") == len(own) and 'depart="200"' in text
    assert all(f'id="{PORTABLE_PREFIX}{v}"' in text for v in own)   # the flows go on numbering from 0


def test_a_flow_still_on_the_road_early(scenario, tmp_path):
    """A start while a flow's first vehicle is still driving: the portable start loads (SUMO numbers
    the flow's later vehicles from .0 again)."""
    from sumo_scendiff.fill.api import fill
    net, routes = scenario
    done = fill(net, routes=(routes,), begin=20.0, out=str(tmp_path / "early"), step_length=1.0)
    assert any(a["vehicle"] == "f_we.0" for a in done.doc["agents"])
    assert done.summary["refused"] == 0 and done.summary["vehicles"] == len(done.doc["agents"])


def test_the_estimate_is_kept_as_an_option():
    from sumo_scendiff.fill.api import FillRequest
    assert FillRequest(routes=("r.rou.xml",)).sumo_start
    assert not FillRequest(routes=("r.rou.xml",), demand_estimate=True).sumo_start
    # a level of its own, or the model placing the demand: the model's fill
    for other in ({"density": 20.0}, {"edge_data": "e.xml"}, {"demand_level_only": True}):
        assert not FillRequest(routes=("r.rou.xml",), **other).sumo_start
    # an area keeps what SUMO's own run has inside it; the estimate only when asked
    assert FillRequest(routes=("r.rou.xml",), area=(0, 0, 9, 9)).sumo_start
    assert not FillRequest(routes=("r.rou.xml",), area=(0, 0, 9, 9), demand_estimate=True).sumo_start


# a part of the crossing: the centre, most of the west and south arms, the start of the north and east
AREA = (-120.0, -120.0, 40.0, 40.0)
# a person walking the west-east road: at 200 s the early one is past the area, the later one in it
PERSONS = ('<routes><person id="p_early" depart="0" departPos="60"><walk edges="wc ce"/></person>'
           '<person id="p_late" depart="120"><walk edges="wc ce"/></person></routes>')


def _own_at(net: str, routes: tuple[str, ...], until: float) -> tuple[dict, dict, int]:
    """Stock SUMO stepped to ``until`` (SUMO's default seed): per vehicle its box centre, per person its
    position, and the vehicles departing in the step after it."""
    from sumo_scendiff.core.geometry import sumo_to_pose
    from sumo_scendiff.sim.scenario import SUMO_DEFAULT_SEED
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    sim = start(SimConfig(net=net, routes=routes, step_length=1.0, begin=0.0, seeding_options=False,
                          seed=SUMO_DEFAULT_SEED))
    try:
        while sim.simulation.getTime() < until - 1e-9:
            sim.simulationStep()
        v = sim.vehicle
        cars = {vid: sumo_to_pose(*v.getPosition(vid), v.getAngle(vid), v.getLength(vid))[:2] for vid in v.getIDList()}
        persons = {pid: sim.person.getPosition(pid) for pid in sim.person.getIDList()}
        sim.simulationStep()
        return cars, persons, len(sim.simulation.getDepartedIDList())
    finally:
        close(sim)


def _first_step(folder: str, cfg: str, tmp_path) -> int:
    """Stock sumo on the folder's ``cfg`` for a few steps: the vehicles running at its first step."""
    import xml.etree.ElementTree as ET

    from sumo_scendiff.core.tools import sumo_binary
    summary = tmp_path / f"{cfg}.summary.xml"
    run = subprocess.run([sumo_binary(), "-c", os.path.join(folder, cfg), "--end", "205", "--no-step-log", "true",
                          "--summary-output", str(summary)], capture_output=True, text=True)
    assert run.returncode == 0 and "rror" not in run.stderr, run.stderr[-400:]
    return int(next(ET.parse(summary).getroot().iter("step")).get("running"))


def _state_vehicles(folder: str, at: float) -> set[str]:
    """The vehicles of the folder's state, loaded in SUMO."""
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    with open(os.path.join(folder, "fill.json")) as f:
        net = json.load(f)["network"]
    sim = start(SimConfig(net=net, begin=at, step_length=1.0, seeding_options=False,
                          extra=("--load-state", os.path.join(folder, "state.xml.gz"))))
    try:
        return set(sim.vehicle.getIDList())
    finally:
        close(sim)


def test_an_area_keeps_sumos_own_vehicles_inside_it(scenario, tmp_path):
    """--area with a demand: SUMO's own run to --begin, the vehicles whose box centre lies outside the
    area (and the persons there) taken out; the rest exactly SUMO's, both starts replaying them."""
    from sumo_scendiff.fill.api import fill
    from sumo_scendiff.fill.tiles import in_area
    net, routes = scenario
    walks = tmp_path / "walks.rou.xml"
    walks.write_text(PERSONS)
    demand = (routes, str(walks))
    done = fill(net, None, AREA, routes=demand, begin=200.0, out=str(tmp_path / "part"), step_length=1.0)
    cars, persons, departing = _own_at(net, demand, 200.0)
    inside = {vid for vid, xy in cars.items() if in_area([xy], AREA)[0]}
    assert 2 < len(inside) < len(cars) - 2           # the area cuts the crossing's traffic
    doc = done.doc
    assert doc["density"]["start"] == "sumo" and doc["area"] == list(AREA)
    assert {a["vehicle"] for a in doc["agents"]} == inside
    for a in doc["agents"]:
        assert (a["x"], a["y"]) == pytest.approx(cars[a["vehicle"]], abs=0.01)
    counts = doc["density"]["vehicles"]
    assert (counts["on_network"], counts["in_area"], counts["outside"]) == (len(cars), len(inside),
                                                                           len(cars) - len(inside))
    assert doc["summary"]["vehicles"] == doc["summary"]["kept"] == len(inside)
    walking_in = sum(bool(in_area([xy], AREA)[0]) for xy in persons.values())
    assert len(persons) == 2 and walking_in == 1
    assert doc["density"]["vehicles"]["persons"] == {"on_network": 2, "in_area": 1, "outside": 1}
    assert _state_vehicles(done.folder, doc["state_time"]) == inside
    for cfg in ("scenario.sumocfg", "start.sumocfg"):    # both starts: the area's vehicles and the demand's next
        assert _first_step(done.folder, cfg, tmp_path) == len(inside) + departing, cfg
    with open(os.path.join(done.folder, "start.rou.xml")) as f:
        assert f.read().count("<vehicle ") == len(inside)


def test_the_cli_writes_it(scenario, tmp_path, capsys):
    from sumo_scendiff.fill.__main__ import get_options, main
    net, routes = scenario
    out = tmp_path / "cli"
    assert main(get_options(["-n", net, "-r", routes, "--begin", "150", "-o", str(out), "-q"])) == 0
    with open(out / "fill.json") as f:
        doc = json.load(f)
    assert doc["density"]["start"] == "sumo" and doc["tiles"] == []
    # the summary line says where the start came from: SUMO's vehicles, no tile of the model's
    n = doc["summary"]["vehicles"]
    printed = capsys.readouterr().out
    assert (f"started from SUMO's own run of the demand to 150 s: {n} of its {n} vehicles are in the start; "
            "the model filled no tile" in printed and n > 3), printed
    assert "filled 0 tiles" not in printed


# a taxi (SUMO's device.taxi) that picks its rider up on ce at 60 s and carries it along ec at 80 s, outside AREA
TAXI = ('<routes><vType id="taxi" vClass="taxi"><param key="has.taxi.device" value="true"/></vType>'
        '<trip id="taxi0" type="taxi" depart="0" from="wc" to="ce" line="taxi"/>'
        '<person id="rider" depart="0"><ride from="ce" to="cn" lines="taxi"/></person></routes>')


def test_an_area_takes_a_taxi_out_with_its_rider(tmp_path):
    """SUMO 1.28 crashed saving the state once TraCI removed a taxi carrying a person (the person still
    pointed at it): the rider is taken out first. In a subprocess, as SUMO's crash ends the process."""
    import sys

    from .conftest import crossing
    net = crossing(str(tmp_path / "cross_u.net.xml"), 1, turnarounds=True)
    (tmp_path / "taxi.rou.xml").write_text(TAXI)
    code = ("import json, sys\nfrom sumo_scendiff.fill.api import fill\n"
            f"done = fill({net!r}, None, {AREA!r}, routes=({str(tmp_path / 'taxi.rou.xml')!r},), begin=80.0, "
            f"out={str(tmp_path / 'out')!r}, step_length=1.0)\n"
            "print(json.dumps(done.doc['density']['vehicles']))\n")
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))     # the package, as installed or not
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=root, timeout=600)
    assert run.returncode == 0, run.stderr[-800:]
    counts = json.loads(run.stdout.strip().splitlines()[-1])
    assert (counts["on_network"], counts["in_area"]) == (1, 0)
    assert counts["persons"] == {"on_network": 1, "in_area": 0, "outside": 1}


RANDOM_DEMAND = """<routes>
  <vType id="car" sigma="0.5" length="5" speedDev="0.2"/>
  <route id="we" edges="wc ce"/><route id="sn" edges="sc cn"/><route id="ws" edges="wc cs"/>
  <flow id="f_we" type="car" route="we" begin="0" end="400" period="7" departSpeed="random"/>
  <flow id="f_sn" type="car" route="sn" begin="0" end="400" probability="0.12"/>
  <flow id="f_x" type="car" route="ws" begin="0" end="400" period="exp(0.1)"/>
</routes>
"""


def _state_poses(path: str) -> dict:
    import gzip
    import xml.etree.ElementTree as ET
    with (gzip.open(path) if path.endswith(".gz") else open(path, "rb")) as f:
        root = ET.parse(f).getroot()
    return {v.get("id"): (v.get("pos"), v.get("speed"), v.get("speedFactor")) for v in root.iter("vehicle")
            if v.get("pos") is not None}


@pytest.mark.parametrize("seed_line", ['<random_number><seed value="42"/></random_number>', ""])
def test_sumos_own_run_is_the_users_whatever_the_fills_seed(cross_net, tmp_path, monkeypatch, seed_line):
    """The demand's random draws (probability and exp() flows, departSpeed="random", speedDev) are
    SUMO's under the configuration's seed (or SUMO's default), not the fill's -s: the state at T holds
    the vehicles of stock ``sumo -c`` at T, each where it stands and as fast."""
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.api import fill
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    (tmp_path / "d.rou.xml").write_text(RANDOM_DEMAND)
    config = tmp_path / "s.sumocfg"
    config.write_text(f'<configuration><input><net-file value="{cross_net}"/><route-files value="d.rou.xml"/>'
                      f'</input>{seed_line}</configuration>')
    stock = tmp_path / "stock.xml"
    run = subprocess.run([sumo_binary(), "-c", str(config), "--end", "201", "--save-state.times", "200",
                          "--save-state.files", str(stock), "--save-state.precision", "6", "--no-step-log", "true"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-400:]
    done = fill(config=str(config), begin=200.0, out=str(tmp_path / "filled"), seed=5)
    assert done.doc["sumo_seed"] == (42 if seed_line else 23423)
    theirs = _state_poses(str(stock))
    assert len(theirs) > 10 and _state_poses(os.path.join(done.folder, "state.xml.gz")) == theirs
