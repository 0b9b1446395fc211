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
    """The vehicles stock SUMO has on the network at ``until`` (libsumo, one step at a time)."""
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    sim = start(SimConfig(net=net, routes=(routes,) if routes else (), additional=additional, step_length=1.0,
                          begin=0.0, seeding_options=False))
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
    for other in ({"density": 20.0}, {"edge_data": "e.xml"}, {"demand_level_only": True}, {"area": (0, 0, 9, 9)}):
        assert not FillRequest(routes=("r.rou.xml",), **other).sumo_start


def test_the_cli_writes_it(scenario, tmp_path, capsys):
    from sumo_scendiff.fill.__main__ import get_options, main
    net, routes = scenario
    out = tmp_path / "cli"
    assert main(get_options(["-n", net, "-r", routes, "--begin", "150", "-o", str(out), "-q"])) == 0
    assert "SUMO's own run" in capsys.readouterr().out
    with open(out / "fill.json") as f:
        assert json.load(f)["density"]["start"] == "sumo"
