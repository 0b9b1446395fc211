"""The user's scenario runs with its own settings (issue 57): its step length (SUMO's default 1 s
where its configuration names none), the sublane model only where it sets lateral-resolution, its
options over the ones the seeding adds, and the exported scenario.sumocfg repeats them. Real SUMO
on tiny networks."""
from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from types import SimpleNamespace

import pytest

from sumo_scendiff.core.tools import sumo_binary
from sumo_scendiff.sim.scenario import scenario_from_files
from sumo_scendiff.sim.sumo import (ADDED_OPTIONS, PRODUCT_STEP_LENGTH, SUMO_STEP_LENGTH, SimConfig, close, settings,
                                    settings_problem, start, step_length_for)

ROOT = Path(__file__).resolve().parent.parent


def _config(tmp_path, net: str, processing: str = "", time: str = "") -> str:
    """A .sumocfg of ``net`` with a short flow, ``time`` and ``processing`` options."""
    rou = tmp_path / "d.rou.xml"
    rou.write_text('<routes><flow id="f" begin="0" end="300" period="4" from="wc" to="ce"/></routes>')
    cfg = tmp_path / "s.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{net}"/><route-files value="{rou}"/></input>'
                   f'<time>{time}</time><processing>{processing}</processing></configuration>')
    return str(cfg)


def _flags(**kw):
    return SimpleNamespace(**{"step_length": None, "lateral_resolution": None, "seeding_options": True, **kw})


def test_the_step_is_the_scenarios_else_sumos_default(cross_net, tmp_path):
    with_step = scenario_from_files(_config(tmp_path, cross_net, time='<step-length value="0.2"/>'))
    assert step_length_for(with_step) == 0.2
    assert step_length_for(with_step, 0.25) == 0.25                       # --step-length wins
    assert step_length_for(scenario_from_files(_config(tmp_path, cross_net))) == SUMO_STEP_LENGTH == 1.0
    demand = scenario_from_files(net=cross_net, routes=[str(tmp_path / "d.rou.xml")])
    assert step_length_for(demand) == SUMO_STEP_LENGTH                    # -r: a user's scenario too
    assert step_length_for(scenario_from_files(net=cross_net)) == PRODUCT_STEP_LENGTH   # a bare network


def test_sublane_only_where_the_scenario_or_the_user_asks():
    assert "--lateral-resolution" not in SimConfig(net="n.net.xml").args()
    theirs = (("lateral-resolution", "0.4"),)
    assert SimConfig(net="n.net.xml", scenario_options=theirs).options()["lateral-resolution"] == "0.4"
    assert SimConfig(net="n.net.xml", scenario_options=theirs, lateral_resolution=0.8).options()["lateral-resolution"] == "0.8"
    assert "lateral-resolution" not in SimConfig(net="n.net.xml", scenario_options=theirs, lateral_resolution=0).options()


def test_the_users_options_win_over_the_seedings():
    theirs = (("collision.check-junctions", "false"), ("time-to-teleport", "-1"), ("lanechange.duration", "3"))
    opts = SimConfig(net="n.net.xml", scenario_options=theirs).options()
    assert opts["collision.check-junctions"] == "false" and opts["time-to-teleport"] == "-1"
    assert opts["lanechange.duration"] == "3" and opts["save-state.precision"] == ADDED_OPTIONS["save-state.precision"]
    assert "time-to-teleport" not in SimConfig(net="n.net.xml").options()    # SUMO's own default
    bare = SimConfig(net="n.net.xml", seeding_options=False).options()
    assert not set(ADDED_OPTIONS) & set(bare)
    # the product's own options are never a scenario's: its inputs, time window and seed (its model is
    # the scenario's: tests/test_meso.py)
    mine = SimConfig(net="n.net.xml", seed=3, scenario_options=(("seed", "9"), ("mesosim", "true"))).options()
    assert mine["seed"] == "3" and mine["mesosim"] == "true"


def test_the_flags_are_checked_and_read(cross_net, tmp_path):
    assert settings_problem(_flags(step_length=0.0)).startswith("--step-length")
    assert settings_problem(_flags(lateral_resolution=-1.0)).startswith("--lateral-resolution")
    assert settings_problem(_flags(lateral_resolution=0.0)) is None
    scen = scenario_from_files(_config(tmp_path, cross_net, processing='<lateral-resolution value="0.6"/>'))
    kw = settings(_flags(seeding_options=False), scen)
    assert kw["step_length"] == SUMO_STEP_LENGTH and not kw["seeding_options"]
    assert SimConfig(net=scen.net, **kw).options()["lateral-resolution"] == "0.6"


def test_a_sweeps_step_is_sumos_default_with_demand(cross_net, tmp_path):
    """A sweep network entry with routes runs at SUMO's 1 s, a bare one at the product's 0.5 s;
    the spec's step_length wins for both."""
    from sumo_scendiff.sweep.spec import SpecError, load_spec
    (tmp_path / "d.rou.xml").write_text('<routes><flow id="f" begin="0" end="300" period="4" from="wc" to="ce"/></routes>')
    nets = (f'networks = [{{net = "{cross_net}"}}, {{net = "{cross_net}", routes = "d.rou.xml"}}]\n'
            'locations = [{center = [0.0, 0.0]}]\n')
    spec = tmp_path / "s.toml"
    spec.write_text(nets)
    assert sorted({s.step_length for s in load_spec(str(spec)).scenarios()}) == [PRODUCT_STEP_LENGTH, SUMO_STEP_LENGTH]
    spec.write_text(nets + "step_length = 0.2\n")
    assert {s.step_length for s in load_spec(str(spec)).scenarios()} == {0.2}
    spec.write_text(nets + "step_length = 0\n")
    with pytest.raises(SpecError, match="step_length: must be > 0"):
        load_spec(str(spec))


def test_sumo_runs_the_scenarios_own_settings(cross_net, tmp_path):
    """What SUMO itself reports it runs with: the configuration's lateral resolution, its junction
    collision setting over the seeding's, SUMO's default step."""
    scen = scenario_from_files(_config(tmp_path, cross_net, processing='<lateral-resolution value="0.6"/>'
                                       '<collision.check-junctions value="false"/>'))
    sim = start(SimConfig(net=scen.net, routes=scen.routes, begin=0.0, **settings(_flags(), scen)))
    try:
        assert sim.simulation.getDeltaT() == 1.0
        assert float(sim.simulation.getOption("lateral-resolution")) == 0.6
        assert sim.simulation.getOption("collision.check-junctions") in ("false", "0")
    finally:
        close(sim)
    sim = start(SimConfig(net=cross_net))      # a bare network: the product's step, no sublane model
    try:
        assert sim.simulation.getDeltaT() == PRODUCT_STEP_LENGTH
        assert float(sim.simulation.getOption("lateral-resolution")) <= 0
    finally:
        close(sim)


@pytest.mark.slow
def test_the_exported_configuration_repeats_the_users_settings(cross_net, tmp_path):
    """run -c on a scenario without a step length and with its own teleport and collision settings:
    scenario.sumocfg has SUMO's 1 s, the user's options, no sublane model, and stock SUMO runs it."""
    cfg = _config(tmp_path, cross_net, processing='<time-to-teleport value="-1"/>'
                                                  '<collision.check-junctions value="false"/>')
    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-c", cfg, "--begin", "60", "--center", "0,0",
                          "--scenes", "1", "--rollout", "2", "--steps", "4", "-o", str(out)],
                         capture_output=True, text=True, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert res.returncode == 0, res.stderr
    exported = out / "scene_000" / "scenario.sumocfg"
    opts = {el.tag: el.get("value") for el in ET.parse(exported).getroot()}
    assert opts["step-length"] == "1" and opts["time-to-teleport"] == "-1"
    assert opts["collision.check-junctions"] == "false" and "lateral-resolution" not in opts
    import sumo
    replay = subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "sumo"), "-c", str(exported), "-e",
                             f"{float(opts['begin']) + 5:g}", "--no-step-log"], capture_output=True, text=True)
    assert replay.returncode == 0, replay.stderr


@pytest.mark.slow
def test_a_fill_keeps_the_scenarios_settings(cross_net, tmp_path):
    """fill -c: the saved state's and the portable start's configurations run at SUMO's 1 s with the
    scenario's options, and --lateral-resolution asks for the sublane model."""
    from sumo_scendiff.fill.__main__ import get_options, main
    cfg = _config(tmp_path, cross_net, processing='<time-to-teleport value="-1"/>')
    out = tmp_path / "filled"
    assert main(get_options(["-c", cfg, "--begin", "60", "--lateral-resolution", "0.4", "-o", str(out)])) == 0
    for name in ("scenario.sumocfg", "start.sumocfg"):
        opts = {el.tag: el.get("value") for el in ET.parse(out / name).getroot()}
        assert opts["step-length"] == "1" and opts["time-to-teleport"] == "-1", name
        assert opts["lateral-resolution"] == "0.4", name


def test_an_ssm_devices_default_output_is_not_written_where_the_user_runs_the_product(cross_net, tmp_path,
                                                                                      monkeypatch):
    """SUMO's SSM device writes ssm_<vehicle>.xml into the working directory unless given a file (stock
    ``sumo -c`` does, here): the product's runs of the scenario (warm-up, seeding, scenes) write none there."""
    cfg = _config(tmp_path, cross_net, processing='<device.ssm.probability value="1"/>')
    stock = tmp_path / "stock"
    stock.mkdir()
    done = subprocess.run([sumo_binary("sumo"), "-c", cfg, "--end", "20", "--no-step-log"], cwd=stock,
                          capture_output=True, text=True)
    assert done.returncode == 0 and list(stock.glob("ssm_*.xml")), done.stderr
    scen = scenario_from_files(cfg)
    assert ("device.ssm.probability", "1") in scen.options
    mine = tmp_path / "mine"
    mine.mkdir()
    monkeypatch.chdir(mine)
    sim = start(SimConfig(net=scen.net, routes=scen.routes, scenario_options=scen.options, step_length=1.0))
    try:
        for _ in range(20):
            sim.simulationStep()
        assert sim.vehicle.getIDCount() > 0
    finally:
        close(sim)
    assert not list(mine.iterdir())
