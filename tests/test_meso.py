"""SUMO's mesoscopic model (``<mesosim value="true"/>``) as a user's configuration runs it: carried by
run (warm-up, seeding, exported folder) and the fill's portable start; the fill's seeding and state are
microscopic, which it says (real SUMO, tiny networks)."""
from __future__ import annotations

import gzip
import json
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from sumo_scendiff.core.tools import sumo_binary
from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.scenario import meso_notice, scenario_from_files
from sumo_scendiff.sim.seeding import Seeder
from sumo_scendiff.sim.sumo import SimConfig, settings

MESO = '<mesoscopic><mesosim value="true"/><meso-edgelength value="50"/><meso-junction-control value="true"/></mesoscopic>'


def _config(folder, net: str, routes: str | None = None) -> str:
    path = folder / "meso.sumocfg"
    files = f'<net-file value="{net}"/>' + (f'<route-files value="{routes}"/>' if routes else "")
    path.write_text(f"<configuration><input>{files}</input>{MESO}</configuration>")
    return str(path)


class Flags:
    step_length = lateral_resolution = None
    seeding_options = True


def test_the_mesoscopic_options_are_carried_and_the_fill_leaves_them_out(cross_net, tmp_path):
    from sumo_scendiff.sim.sumo import microscopic
    cfg = _config(tmp_path, cross_net)
    scen = scenario_from_files(config=cfg)
    meso = {"mesosim": "true", "meso-edgelength": "50", "meso-junction-control": "true"}
    options = SimConfig(net=scen.net, **settings(Flags, scen)).options()
    assert meso.items() <= options.items()
    fill = SimConfig(net=scen.net, **settings(Flags, scen, mesoscopic=False)).options()
    assert not set(meso) & set(fill) and microscopic((("mesosim", "true"), ("scale", "2"))) == (("scale", "2"),)
    assert "mesoscopic model" in meso_notice(cfg) and "microscopically" in meso_notice(cfg, fill=True)
    plain = tmp_path / "plain.sumocfg"
    plain.write_text(f'<configuration><input><net-file value="{cross_net}"/></input></configuration>')
    assert meso_notice(str(plain)) is None


def test_the_seeder_places_into_the_segments_of_their_edges(cross_net, cross_scene):
    """In the mesoscopic model a vehicle stands in a segment of its edge (SUMO reports the segment's
    start as its position): placed = SUMO has it on its pose's edge; the agent turning inside the junction
    (no segment there) stands at the end of the edge it comes from: misplaced, its distance recorded.
    Every placed or misplaced agent is a vehicle in SUMO; the counts add up."""
    import libsumo as sim
    net = Network.load(cross_net)
    scene = cross_scene(net)
    sim.start(["sumo", "-n", cross_net, "--mesosim", "true", "--meso-edgelength", "50", "--no-step-log"])
    try:
        seeder = Seeder(sim, net)
        report = seeder.seed(scene)
        sim.simulationStep()
        report = seeder.verify(report)
        seeder.settle(report)
        assert seeder.meso and set(report.refused) == {4}
        assert report.placed == 3 and set(report.misplaced) == {3} and report.misplaced[3] > 0
        assert set(report.ids.values()) <= set(sim.vehicle.getIDList())
        assert [sim.vehicle.getRoadID(report.ids[i]) for i in (0, 1, 2)] == ["wc", "wc", "sc"]
        # SUMO put the eastbound pair into the segment of their fronts (the edge is 4 segments long)
        assert sim.vehicle.getLanePosition(report.ids[0]) > 0
        assert sum(report.counts(len(scene)).values()) == 2 * len(scene)
    finally:
        sim.close()


@pytest.mark.slow
def test_a_mesoscopic_run_replays_in_stock_sumo_as_the_scene_says(cross_net, tmp_path):
    """The run warmed up microscopically and exported microscopic folders: the scene held what a
    microscopic run of the demand had, not the configuration's own traffic. Now its background is the
    mesoscopic run's, its folder replays the user's model, and stock SUMO holds what the scene says."""
    routes = tmp_path / "demand.rou.xml"
    routes.write_text("<routes>" + "".join(
        f'<vehicle id="v{k}" depart="{k}"><route edges="wc ce"/></vehicle>'
        f'<vehicle id="n{k}" depart="{k}"><route edges="sc cn"/></vehicle>' for k in range(40)) + "</routes>")
    cfg = _config(tmp_path, cross_net, str(routes))
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-c", cfg, "--begin", "30", "--center", "0,0",
                           "--vehicles", "14", "--scenes", "1", "--rollout", "2", "--steps", "8", "-o", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-500:]
    assert sum("mesosim" in ln for ln in done.stderr.splitlines()) == 1     # said once
    scene = out / "scene_000"
    kept = {el.tag: el.get("value") for el in ET.parse(scene / "scenario.sumocfg").getroot()}
    assert kept["mesosim"] == "true" and kept["meso-edgelength"] == "50" and kept["meso-junction-control"] == "true"
    with gzip.open(scene / "state.xml.gz", "rt") as f:
        assert 'type="meso"' in f.read(2000)
    doc = json.loads((scene / "scene.json").read_text())
    seeded = sum(a["status"] in ("placed", "misplaced") for a in doc["agents"])
    assert doc["counts"]["placed"] > 0
    t = doc["time"]
    stock = _held(cfg, ["--end", f"{t + 1:g}"], tmp_path / "stock.xml", t)   # the user's own run: their seed
    replay = _held(str(scene / "scenario.sumocfg"), ["--end", f"{t + 1:g}"], tmp_path / "replay.xml", t)
    assert replay == stock + seeded, (replay, stock, seeded)


@pytest.mark.slow
def test_the_fills_portable_start_runs_the_mesoscopic_model(cross_net, tmp_path):
    """The fill seeds and saves its state microscopically (SUMO loads no microscopic state into its
    mesoscopic model): its scenario.sumocfg is microscopic, said once; its portable start, which holds no
    state, runs the configuration's model and holds what fill.json seeded (the demand departed by then)."""
    routes = tmp_path / "demand.rou.xml"
    routes.write_text("<routes>" + "".join(f'<vehicle id="v{k}" depart="{k}"><route edges="wc ce"/></vehicle>'
                                           for k in range(30)) + "</routes>")
    cfg = _config(tmp_path, cross_net, str(routes))
    out = tmp_path / "fill"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-c", cfg, "--begin", "35", "-o", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-500:]
    assert sum("mesosim" in ln for ln in done.stderr.splitlines()) == 1
    state = {el.tag for el in ET.parse(out / "scenario.sumocfg").getroot()}
    start = {el.tag: el.get("value") for el in ET.parse(out / "start.sumocfg").getroot()}
    assert not {"mesosim", "meso-edgelength"} & state
    assert start["mesosim"] == "true" and start["meso-edgelength"] == "50"
    doc = json.loads((out / "fill.json").read_text())
    seeded = sum(a["status"] in ("placed", "misplaced") for a in doc["agents"])
    assert doc["start_model"] == {"model": "mesoscopic"} and seeded > 0
    t = doc["state_time"]
    assert _held(str(out / "start.sumocfg"), ["--end", f"{t + 1:g}"], tmp_path / "start.xml", t) == seeded


def _held(cfg: str, args: list[str], summary, t: float) -> int:
    """Stock SUMO's vehicles on the road or waiting to enter at ``t`` on configuration ``cfg``."""
    ran = subprocess.run([sumo_binary("sumo"), "-c", cfg, *args, "--no-step-log", "--summary-output", str(summary)],
                         capture_output=True, text=True)
    assert ran.returncode == 0, ran.stderr[-300:]
    step = next(el for el in ET.parse(summary).getroot() if abs(float(el.get("time")) - t) < 1e-6)
    return int(step.get("running")) + int(step.get("waiting"))


def test_replay_future_is_refused_in_the_mesoscopic_model(cross_net, tmp_path, capsys):
    """``--replay-future`` holds the agents on their generated poses (moveToXY), which SUMO's mesoscopic
    model does not do: one line, exit 2, rather than a rollout.json saying they were held."""
    from sumo_scendiff import run as run_cli
    try:
        code = run_cli.main(run_cli.get_options(["-c", _config(tmp_path, cross_net), "--replay-future", "1",
                                                 "-o", str(tmp_path / "out")]))
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and "--replay-future" in err and "mesosim" in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()
