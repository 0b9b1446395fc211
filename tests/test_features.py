"""SUMO features that real-world scenarios use, each a case the corpus's feature matrix found
(benchmarks/scenarios_features.py builds the variants: a small generated grid plus one feature), run at
small scale against the real SUMO."""
from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from sumo_scendiff.sim.scenario import scenario_from_files
from sumo_scendiff.sim.sumo import SimConfig, close, settings, start
from sumo_scendiff.sim.warmup import warm_state, warm_up

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def features():
    spec = importlib.util.spec_from_file_location("scenarios_features", BENCH / "scenarios_features.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def variant(features, name: str, folder: Path) -> Path:
    """The feature variant ``name`` (a key of FEATURES) built in ``folder``; its configuration."""
    folder.mkdir(parents=True, exist_ok=True)
    build, _, kw = features.FEATURES[name]
    build(folder)
    return folder / kw.get("config", "scenario.sumocfg")


def scenario_config(cfg: Path) -> SimConfig:
    """The SUMO run of a user's configuration as run -c and fill -c start it (sim.sumo.settings)."""
    scen = scenario_from_files(config=str(cfg))

    class Flags:
        step_length = lateral_resolution = None
        seeding_options = True
    return SimConfig(net=scen.net, routes=scen.routes, additional=scen.additional, begin=scen.begin,
                     **settings(Flags, scen))


def _persons_at(sim) -> set:
    return set(sim.person.getIDList())


def test_the_persons_on_the_road_at_begin_are_in_the_warm_state(features, tmp_path):
    """Persons walking and riding a bus at T: SUMO leaves them out of a saved state unless asked
    (save-state.transportables), so the warm-up's state, and every scene started from it, lost them."""
    cfg = scenario_config(variant(features, "feat_persons", tmp_path / "s"))
    sim = start(cfg)
    try:
        warm_up(sim, 120.0)
        ref = _persons_at(sim)
    finally:
        close(sim)
    assert len(ref) > 5
    sim = start(replace(cfg, state=warm_state(cfg, 120.0, folder=str(tmp_path / "states"))))
    try:
        assert _persons_at(sim) == ref
    finally:
        close(sim)


def test_a_calibrator_in_the_additional_files_leaves_the_demand_routable(features, tmp_path):
    """A calibrator (with the <flow> it holds its edge's count by), a variable speed sign and a rerouter
    closing an edge: stock SUMO runs them, and duarouter, given the calibrator, ended without a word,
    so the fill refused the scenario."""
    from sumo_scendiff.fill.routing import routed_departures
    cfg = variant(features, "feat_traffic_control", tmp_path / "s")
    scen = scenario_from_files(config=str(cfg))
    departures, unrouted = routed_departures(scen.net, scen.routes, scen.additional, until=120.0)
    assert len(departures) > 30 and unrouted == 0
    assert "<calibrator" in (tmp_path / "s" / "control.add.xml").read_text()     # the user's file as it was


def test_a_stop_until_a_time_holds_its_vehicle_in_the_fills_estimate(features, tmp_path):
    """``<stop lane=... until="140"/>``: at 120 s stock SUMO has the vehicles standing at their stop; the
    fill's estimate read only a stop's duration and had them long arrived."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.map.network import Network
    cfg = variant(features, "feat_parking", tmp_path / "s")
    scen = scenario_from_files(config=str(cfg))
    est = DemandEstimate.at(Network.load(scen.net), scen.routes, begin=120.0, additional=scen.additional)
    waiting = {r.id: r.edges[0] for r in est.en_route if r.id.startswith("waiter.")}
    sim = start(scenario_config(cfg))
    try:
        warm_up(sim, 120.0)
        ref = {v: sim.vehicle.getRoadID(v) for v in sim.vehicle.getIDList() if v.startswith("waiter.")}
        standing = {v for v in ref if sim.vehicle.isStopped(v)}
    finally:
        close(sim)
    assert standing and set(ref) <= set(waiting), (ref, waiting)
    assert {v: waiting[v] for v in standing} == {v: ref[v] for v in standing}


def test_a_state_of_a_scaled_demand_loads_again(features, tmp_path):
    """``--scale 2`` (with the other insertion options: no teleporting, route errors ignored, a maximum
    departure delay, collisions removed): SUMO saves the copy ``pas4.1`` naming its owner's route
    ``!pas4``, which it leaves out of the state once ``pas4`` arrived, and refuses to load its own
    state; the warm-up, run -c and the exported scenes all start from one."""
    cfg = scenario_config(variant(features, "feat_options_insertion", tmp_path / "s"))
    sim = start(cfg)
    try:
        warm_up(sim, 120.0)
        ref = set(sim.vehicle.getIDList())
    finally:
        close(sim)
    assert any(v.endswith(".1") for v in ref)          # the copies --scale makes
    sim = start(replace(cfg, state=warm_state(cfg, 120.0, folder=str(tmp_path / "states"))))
    try:
        assert set(sim.vehicle.getIDList()) == ref
    finally:
        close(sim)


def test_the_fills_estimate_scales_the_demand_as_sumo_does(features, tmp_path):
    """``--scale 2``: SUMO drives a copy of every vehicle (``pas4.1`` beside ``pas4``); the fill's estimate
    routed the demand unscaled and placed half the vehicles SUMO has on the road."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.map.network import Network
    cfg = variant(features, "feat_options_insertion", tmp_path / "s")
    scen = scenario_from_files(config=str(cfg))
    options = dict(scen.options)
    est = DemandEstimate.at(Network.load(scen.net), scen.routes, begin=120.0, scale=options["scale"])
    sim = start(scenario_config(cfg))
    try:
        warm_up(sim, 120.0)
        running = set(sim.vehicle.getIDList())
    finally:
        close(sim)
    copies = {r.id for r in est.en_route if r.id.endswith(".1")}
    assert copies and copies & running
    assert est.departed == 2 * DemandEstimate.at(Network.load(scen.net), scen.routes, begin=120.0).departed


def _running_after_a_step(cfg: Path, tmp_path: Path) -> int:
    """Vehicles on the road after stock SUMO's first step of a configuration."""
    import subprocess
    import xml.etree.ElementTree as ET

    from sumo_scendiff.core.tools import sumo_binary
    fcd = tmp_path / f"{cfg.stem}.fcd.xml"
    done = subprocess.run([sumo_binary("sumo"), "-c", str(cfg), "--fcd-output", str(fcd), "--no-step-log",
                           "--end", "122"], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-300:]
    return len(list(next(iter(ET.parse(fcd).getroot()))))


def test_the_fills_portable_start_is_not_scaled_twice(features, tmp_path):
    """``--scale 2``: SUMO scales the portable start's vehicles too, which are those on the road, copies
    included: the fill from SUMO's run stopped ("Another vehicle with the id 'start.pas27.1' exists") and
    the fill from the estimate started with every vehicle twice, stacked."""
    import subprocess
    cfg = variant(features, "feat_options_insertion", tmp_path / "s")
    out = tmp_path / "fill"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-c", str(cfg), "--begin", "120",
                           "-o", str(out)], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-300:]
    running = _running_after_a_step(out / "scenario.sumocfg", tmp_path)
    # the state holds the vehicles still waiting to enter at T (they enter on its first steps); the
    # portable start does not carry them (docs/fill.md): scaled twice, it would hold about twice as many
    waiting = json.loads((out / "fill.json").read_text())["density"]["waiting_to_enter"]
    assert running > 10 and running - waiting <= _running_after_a_step(out / "start.sumocfg", tmp_path) <= running


def test_a_mesoscopic_scenario_is_said_to_run_microscopically(features, tmp_path):
    """``<mesosim value="true"/>``: the fill builds its start from lane positions, which only SUMO's
    microscopic model has, so it runs the scenario microscopically; it did so without a word (run carries
    the model: tests/test_meso.py)."""
    import subprocess
    cfg = variant(features, "feat_meso", tmp_path / "s")
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-c", str(cfg), "--begin", "120",
                           "-o", str(tmp_path / "fill")], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-300:]
    assert any("mesosim" in ln and "microscopic" in ln for ln in done.stderr.splitlines()), done.stderr


def test_a_route_file_that_includes_another_travels_with_it(features, tmp_path):
    """``<include href="included.rou.xml"/>`` in a route file: the exported folder had the route file and
    not the one it includes, and stock SUMO said "Cannot read file" (and went on without its demand)."""
    import subprocess

    from sumo_scendiff.core.tools import sumo_binary
    cfg = variant(features, "feat_departures", tmp_path / "s")
    out = tmp_path / "fill"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-c", str(cfg), "--begin", "100",
                           "-o", str(out)], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-300:]
    assert (out / "included.rou.xml").is_file()
    for name in ("scenario.sumocfg", "start.sumocfg"):
        ran = subprocess.run([sumo_binary("sumo"), "-c", str(out / name), "--end", "130", "--no-step-log"],
                             capture_output=True, text=True, cwd=tmp_path)
        assert ran.returncode == 0 and "Error" not in ran.stderr, ran.stderr[-300:]


def test_a_variable_speed_signs_own_file_travels_with_its_additional_file(features, tmp_path):
    """``<variableSpeedSign ... file="speeds/vss.xml"/>``: the exported folder had the additional file
    and not the definitions it reads, and stock SUMO refused the folder."""
    import subprocess

    from sumo_scendiff.core.tools import sumo_binary
    cfg = variant(features, "feat_traffic_control", tmp_path / "s")
    out = tmp_path / "fill"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-c", str(cfg), "--begin", "120",
                           "-o", str(out)], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-300:]
    assert (out / "speeds" / "vss.xml").is_file()
    ran = subprocess.run([sumo_binary("sumo"), "-c", str(out / "start.sumocfg"), "--end", "130", "--no-step-log"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert ran.returncode == 0 and "Error" not in ran.stderr, ran.stderr[-300:]
