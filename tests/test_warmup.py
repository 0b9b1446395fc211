"""sim/warmup.py: the demand run to T in one call, its state saved and started from when asked again."""
from __future__ import annotations

import os

import pytest

from sumo_scendiff.sim.sumo import SimConfig, close, start
from sumo_scendiff.sim.warmup import WarmUpError, cached_state, start_warm, state_key, warm_config, warm_up

DEMAND = """<routes>
  <vType id="car" accel="2.6" decel="4.5" sigma="0.5" length="5"/>
  <route id="we" edges="wc ce"/><route id="sn" edges="sc cn"/><route id="ws" edges="wc cs"/>
  <flow id="f_we" type="car" route="we" begin="0" end="400" period="7"/>
  <flow id="f_sn" type="car" route="sn" begin="0" end="400" probability="0.12"/>
  <vehicle id="late" type="car" route="ws" depart="150"/>
</routes>
"""
# DEMAND at a junction without a light whose minor road's drivers ignore the major road's vehicles,
# approaching and inside the junction: they collide in it, where SUMO looks for collisions only with
# collision.check-junctions (an option the seeding adds, not the user's), and the state at a time
# differs with it (a vehicle teleported on collision arrives earlier)
RECKLESS = DEMAND.replace('<vType id="car"', '<vType id="reckless" accel="2.6" decel="4.5" sigma="0.5" length="5" '
                          'jmIgnoreFoeProb="1" jmIgnoreFoeSpeed="100" jmIgnoreJunctionFoeProb="1"/>\n  <vType id="car"'
                          ).replace('type="car" route="we" begin="0" end="400" period="7"',
                                    'type="car" route="we" begin="0" end="400" period="3"'
                          ).replace('type="car" route="sn" begin="0" end="400" probability="0.12"',
                                    'type="reckless" route="sn" begin="0" end="400" period="4"')


@pytest.fixture()
def scenario(cross_net, tmp_path):
    routes = tmp_path / "demand.rou.xml"
    routes.write_text(DEMAND)
    return SimConfig(net=cross_net, routes=(str(routes),), step_length=1.0, begin=0.0)


def _snapshot(sim) -> dict:
    v = sim.vehicle
    return {vid: (round(v.getPosition(vid)[0], 3), round(v.getPosition(vid)[1], 3), round(v.getSpeed(vid), 3))
            for vid in v.getIDList()}


def _stepped(cfg, until: float, then: float = 0.0) -> tuple[dict, dict]:
    """The vehicles at ``until`` stepping one step at a time (the reference), and ``then`` s later."""
    sim = start(cfg)
    try:
        while sim.simulation.getTime() < until - 1e-9:
            sim.simulationStep()
        at = _snapshot(sim)
        for _ in range(int(then)):
            sim.simulationStep()
        return at, _snapshot(sim)
    finally:
        close(sim)


def test_one_call_is_the_step_by_step_run(scenario, tmp_path):
    ref, _ = _stepped(scenario, 200.0)
    sim = start(scenario)
    try:
        assert warm_up(sim, 200.0) is None        # no cfg: nothing saved
        assert sim.simulation.getTime() == pytest.approx(200.0)
        assert _snapshot(sim) == ref and len(ref) > 3
        with pytest.raises(WarmUpError, match="already at 200"):
            warm_up(sim, 100.0)
    finally:
        close(sim)


def _continued(sim, seconds: int) -> tuple[dict, dict]:
    try:
        at = _snapshot(sim)
        for _ in range(seconds):
            sim.simulationStep()
        return at, _snapshot(sim)
    finally:
        close(sim)


def test_the_saved_state_is_started_from_and_continues_the_same(scenario, tmp_path):
    folder, warming = str(tmp_path / "states"), warm_config(scenario)
    ref, _ = _stepped(warming, 200.0)     # the scenario as stock SUMO runs it, one step at a time
    assert cached_state(warming, 200.0, folder) is None
    sim = start_warm(scenario, 200.0, folder=folder)
    assert sim.simulation.getTime() == pytest.approx(200.0)
    first = _continued(sim, 60)
    path = cached_state(warming, 200.0, folder)
    assert path is not None and os.listdir(folder) == [os.path.basename(path)]
    stamp = os.stat(path).st_mtime_ns
    sim = start_warm(scenario, 200.0, folder=folder)     # from the state: not run again, not rewritten
    assert sim.simulation.getTime() == pytest.approx(200.0)
    again = _continued(sim, 60)
    assert first[0] == ref          # the demand's vehicles at T as SUMO ran them
    assert again == first           # and on: the flows go on the same way, none inserted twice
    assert os.stat(path).st_mtime_ns == stamp


def test_the_key_follows_the_inputs_contents_and_the_time(scenario):
    key = state_key(scenario, 200.0)
    assert state_key(scenario, 200.0) == key
    assert state_key(scenario, 201.0) != key
    assert state_key(warm_config(scenario), 200.0) != key      # without the seeding's options
    assert state_key(warm_config(scenario, rng=False), 200.0) == state_key(warm_config(scenario), 200.0)
    with open(scenario.routes[0], "a") as f:
        f.write("<!-- edited -->\n")
    assert state_key(scenario, 200.0) != key


def _state_ids(path: str) -> set[str]:
    import gzip
    import xml.etree.ElementTree as ET
    with (gzip.open(path) if path.endswith(".gz") else open(path, "rb")) as f:
        return {v.get("id") for v in ET.parse(f).getroot().iter("vehicle")}


def _user_scenario(tmp_path, net: str, seed_line: str = "", demand: str = DEMAND):
    """``demand`` in a configuration of the user's (``seed_line``: its random_number section, if any)."""
    (tmp_path / "d.rou.xml").write_text(demand)
    config = tmp_path / "s.sumocfg"
    config.write_text(f'<configuration><input><net-file value="{net}"/><route-files value="d.rou.xml"/>'
                      f'</input>{seed_line}</configuration>')
    return config


def _stock_ids(config, t: float, tmp_path, *extra: str) -> set[str]:
    """The vehicles stock ``sumo -c config`` (``extra``: more options) holds at ``t`` (its saved state's)."""
    import subprocess

    from sumo_scendiff.core.tools import sumo_binary
    stock = tmp_path / "stock.xml"
    done = subprocess.run([sumo_binary(), "-c", str(config), "--end", f"{t + 1:g}", "--save-state.times", f"{t:g}",
                           "--save-state.files", str(stock), "--no-step-log", "true", *extra], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-400:]
    return _state_ids(str(stock))


def _run(config, tmp_path, *args: str):
    import subprocess
    import sys
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-c", str(config), "-s", "5", "--rollout", "0",
                           "-o", str(out), *args], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-400:]
    return out


def _kept(out, scene: str) -> set[str]:
    """The demand's vehicles in a scene's state after the seeding step (the seeded ones left out)."""
    return {v for v in _state_ids(str(out / scene / "state.xml.gz")) if not v.startswith("sd")}


@pytest.mark.parametrize("seed_line", ['<random_number><seed value="42"/></random_number>', ""])
def test_run_warms_the_demand_with_the_users_sumo_seed(cross_net, tmp_path, monkeypatch, seed_line):
    """``run -c`` runs the demand to --begin as the user's own ``sumo -c`` runs it: under the
    configuration's seed (else SUMO's default), not ``-s`` (the model's), and every scene goes on under
    it. The probability flow's departures at T+1 (the state after the seeding step) are stock SUMO's:
    it departed other vehicles under the run's -s."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    config = _user_scenario(tmp_path, cross_net, seed_line)
    theirs = _stock_ids(config, 201, tmp_path)
    out = _run(config, tmp_path, "--begin", "200", "--scenes", "2", "--center", "0,0")
    assert len(theirs) > 5
    for scene in ("scene_000", "scene_001"):   # the first on the warm simulation, the second started from its state
        assert _kept(out, scene) == theirs, scene


def test_run_waits_for_its_ego_as_the_users_sumo_runs(priority_net, tmp_path, monkeypatch):
    """``run --ego``: the demand runs until the ego has driven --ego-after as the user's own sumo runs it
    (their seed and options, none of the seeding's), and the scene goes on from there: the state
    after the seeding step holds stock SUMO's vehicles at that time, whatever -s is. Cars colliding
    inside the junction (RECKLESS): with the seeding's collision.check-junctions during the wait, as
    the wait ran before, SUMO teleports them and holds other vehicles then (one of 32 missing)."""
    import json
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    config = _user_scenario(tmp_path, priority_net, demand=RECKLESS)
    out = _run(config, tmp_path, "--ego", "late", "--ego-after", "9", "--scenes", "1")
    t = json.loads((out / "scene_000" / "scene.json").read_text())["time"]
    theirs = _stock_ids(config, t, tmp_path)
    assert _stock_ids(config, t, tmp_path, "--collision.check-junctions", "true") != theirs   # the case tells
    assert len(theirs) > 5 and "late" in theirs and _kept(out, "scene_000") == theirs


LATE_FLOW = """<routes>
    <flow id="f" begin="500" end="700" period="7" from="A0A1" to="C1C2"/>
</routes>
"""


@pytest.fixture(scope="module")
def actuated_grid(tmp_path_factory) -> str:
    """A 3x3 grid whose every junction has an actuated light (netgenerate, as osmWebWizard guesses them)."""
    import subprocess

    from sumo_scendiff.core.tools import sumo_binary
    net = str(tmp_path_factory.mktemp("actuated") / "grid.net.xml")
    netgenerate = os.path.join(os.path.dirname(sumo_binary()), "netgenerate")
    done = subprocess.run([netgenerate, "--grid", "--grid.number", "3", "--grid.length", "200", "--tls.guess", "true",
                           "--default-junction-type", "traffic_light", "--tls.default-type", "actuated", "-o", net],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-400:]
    return net


def test_a_configuration_without_begin_starts_at_sumos_zero(actuated_grid, tmp_path, monkeypatch):
    """A configuration naming no begin is run from SUMO's default 0, as stock ``sumo -c`` runs it, not
    from the demand's first departure: actuated lights start their program at SUMO's begin, so a later
    start holds other vehicles at T (here one more of the flow on the road)."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    config = _user_scenario(tmp_path, actuated_grid, demand=LATE_FLOW)
    theirs = _stock_ids(config, 651, tmp_path)
    assert _stock_ids(config, 651, tmp_path, "-b", "500") != theirs   # the case tells: two more on the road
    out = _run(config, tmp_path, "--begin", "650", "--scenes", "1", "--center", "200,200", "--vehicles", "0")
    assert theirs and _kept(out, "scene_000") == theirs
