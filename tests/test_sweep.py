"""Sweeps: spec validation, the index, a network failing in one entry, resume after SIGKILL, Ray."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from sumo_scendiff.core.outputs import LOCK
from sumo_scendiff.sweep.__main__ import get_options, main
from sumo_scendiff.sweep.spec import SpecError, load_spec

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SPEC = """name = "t"
networks = ["{net}"]
locations = [{{center = [0.0, 0.0]}}, {{auto = 1}}]
p_mask = [0.3, 0.9]
seeds = 2
steps = 4
rollout = 2.0

[[token_sets]]
name = "key"
agents = [{{x = 20.0, y = -1.6, heading = 0.0, speed = 8.0}}]
vary = {{final_speed = [0.0, 8.0]}}
"""


@pytest.fixture(scope="module")
def spec_file(cross_net, tmp_path_factory):
    path = tmp_path_factory.mktemp("spec") / "sweep.toml"
    path.write_text(SPEC.format(net=cross_net))
    return str(path)


def _main(args, capsys):
    try:
        code = main(get_options(args))
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def _index(out) -> list[dict]:
    with open(os.path.join(out, "index.jsonl")) as f:
        return [json.loads(line) for line in f]


def test_spec_expands_the_cross_product(spec_file):
    spec = load_spec(spec_file)
    sc = spec.scenarios()
    assert len(sc) == 2 * 2 * 2 * 2   # locations x token variants x p_mask x seeds
    assert [s.id for s in sc[:3]] == ["s0000", "s0001", "s0002"]
    assert sorted(spec.token_sets) == ["key[final_speed=0]", "key[final_speed=8]"]
    assert spec.token_sets["key[final_speed=0]"].agents[0]["final_speed"] == 0.0
    assert {s.location for s in sc} == {"0,0", "auto:0"} and {s.seed for s in sc} == {0, 1}



def test_a_spec_without_density_keeps_its_plan(spec_file):
    """No density/vehicles key: the plan and ids of before the key (one level, the model's prior);
    params() keeps its keys and adds the two, unset."""
    import itertools
    spec = load_spec(spec_file)
    sc = spec.scenarios()
    want = list(itertools.product(["0,0", "auto:0"], ["key[final_speed=0]", "key[final_speed=8]"],
                                  [0.3, 0.9], [0, 1]))
    assert [(s.location, s.token_set, s.p_mask, s.seed) for s in sc] == want
    assert [s.id for s in sc] == [f"s{k:04d}" for k in range(16)]
    p = sc[5].params()
    assert (p["id"], p["location"], p["token_set"], p["p_mask"], p["seed"]) == \
        ("s0005", "0,0", "key[final_speed=8]", 0.3, 1)
    assert {"id", "network", "location", "token_set", "p_mask", "seed", "steps", "rollout", "step_length",
            "replay"} <= set(p) and p["density"] is None and p["vehicles"] is None
    assert all(s.density is None and s.vehicles is None for s in sc)
    assert len(load_spec(os.path.join(ROOT, "scenarios", "density.json")).scenarios()) == 24


def test_density_is_an_axis_crossed_with_the_others(cross_net, tmp_path):
    path = tmp_path / "levels.toml"
    base = f'networks = ["{cross_net}"]\nlocations = [{{center = [0.0, 0.0]}}]\np_mask = [0.3, 0.9]\nseeds = 2\n'
    path.write_text(base + 'density = [10, 30.5, "auto"]\n')
    sc = load_spec(str(path)).scenarios()
    assert len(sc) == 2 * 3 * 2                     # p_mask x density x seeds, seeds innermost
    assert [(s.p_mask, s.density, s.seed) for s in sc[:6]] == \
        [(0.3, 10.0, 0), (0.3, 10.0, 1), (0.3, 30.5, 0), (0.3, 30.5, 1), (0.3, "auto", 0), (0.3, "auto", 1)]
    assert all(s.vehicles is None for s in sc) and sc[4].params()["density"] == "auto"
    path.write_text(base + 'vehicles = [5, 10]\n')
    sc = load_spec(str(path)).scenarios()
    assert [(s.p_mask, s.vehicles, s.seed) for s in sc[:4]] == [(0.3, 5, 0), (0.3, 5, 1), (0.3, 10, 0), (0.3, 10, 1)]
    assert all(s.density is None and isinstance(s.vehicles, int) for s in sc)
    path.write_text(f'networks = ["{cross_net}"]\n'
                    '[[scenarios]]\nlocation = "0,0"\ndensity = "auto"\n'
                    '[[scenarios]]\nlocation = "0,0"\nvehicles = 7\n'
                    '[[scenarios]]\nlocation = "0,0"\ndensity = 12\nseed = 3\n'
                    '[[scenarios]]\nlocation = "0,0"\n')
    sc = load_spec(str(path)).scenarios()
    assert [(s.density, s.vehicles, s.seed) for s in sc] == [("auto", None, 0), (None, 7, 0), (12.0, None, 3),
                                                            (None, None, 0)]


def test_unset_sampler_settings_are_the_generators_defaults(cross_net, tmp_path):
    from sumo_scendiff.generation.generator import GenerationConfig
    path = tmp_path / "bare.toml"
    path.write_text(f'networks = ["{cross_net}"]\nlocations = [{{center = [0.0, 0.0]}}]\n')
    (s,) = load_spec(str(path)).scenarios()
    g = GenerationConfig()
    assert (s.steps, s.guidance, s.threshold, s.scene_guidance) == (g.steps, g.guidance, g.threshold, None)
    assert s.pin_tokens is g.pin_tokens is True and s.pin_speeds is g.pin_speeds is True
    assert s.lane_headings is g.lane_headings is True and s.lane_snap is g.lane_snap is True
    path.write_text(path.read_text() + "pin_tokens = false\npin_speeds = false\nlane_snap = false\n")
    (s,) = load_spec(str(path)).scenarios()
    assert s.pin_tokens is False and s.params()["pin_tokens"] is False
    assert s.lane_snap is False and s.lane_headings is True and s.pin_speeds is False


def test_a_networks_begin_is_a_time_on_sumos_clock(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('networks = [{net = "x.net.xml", routes = "x.rou.xml", begin = "8:00:00"}, '
                    '{net = "y.net.xml", begin = 600}]\nlocations = [{auto = 1}]\n')
    nets = load_spec(str(path)).networks
    assert (nets["x"].begin, nets["y"].begin) == (28800.0, 600.0)


def test_batches_depend_on_the_plan_alone(spec_file):
    from sumo_scendiff.sweep.engines import tasks
    sc = load_spec(spec_file).scenarios()
    full = tasks(sc)
    assert sorted(s.id for batch, _ in full for s in batch) == sorted(s.id for s in sc)
    assert all(not done for _, done in full) and max(len(b) for b, _ in full) == 2  # 16 -> 8 batches
    # a resume with some scenarios finished: the same batches (those with work left), done ones marked
    todo = {s.id for s in sc[5:]}
    resumed = tasks(sc, todo)
    assert [b for b, _ in resumed] == [b for b, _ in full if any(s.id in todo for s in b)]
    assert set().union(*(done for _, done in resumed)) == {s.id for s in sc[:5]} - \
        {s.id for b, _ in full if all(x.id not in todo for x in b) for s in b}


@pytest.mark.parametrize("body, message", [
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\nsedes = [1]\n', "sedes: unknown key"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\nseeds = "many"\n', "seeds: must be"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\nseeds = []\n', "empty"),
    ('networks = ["x.net.xml"]\nlocations = [{somewhere = 1}]\n', "locations[0].somewhere: unknown key"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\np_mask = [1.5]\n', "p_mask"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\nguidance = -1.0\n', "guidance"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\npin_tokens = 1\n', "pin_tokens: must be bool"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\nlane_snap = "no"\n', "lane_snap: must be bool"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\n[[token_sets]]\nagents = [{speed = -1}]\n',
     "token_sets[0]: agents[0]"),
    ('networks = ["x.net.xml"]\n[[scenarios]]\nlocation = "auto:0"\ntoken_set = "nope"\n', "not defined"),
    ('networks = ["x.net.xml"\n', "not valid TOML"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\ndensity = 30\n', "density: must be list"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\ndensity = [10, -1]\n', "density: values must be"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\ndensity = ["lots"]\n', "density: values must be"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\ndensity = [true]\n', "density: values must be"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\ndensity = [nan]\n', "density: values must be"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\ndensity = []\n', "empty"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\nvehicles = [2.5]\n', "vehicles: values must be"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\nvehicles = ["auto"]\n', "vehicles: values must be"),
    ('networks = ["x.net.xml"]\nlocations = [{auto = 1}]\ndensity = [10]\nvehicles = [5]\n',
     "vehicles: give either density or vehicles"),
    ('networks = ["x.net.xml"]\n[[scenarios]]\nlocation = "auto:0"\ndensity = -3\n',
     "scenarios[0].density: values must be"),
    ('networks = ["x.net.xml"]\n[[scenarios]]\nlocation = "auto:0"\ndensity = 3\nvehicles = 2\n',
     "scenarios[0].vehicles: give either"),
    ('networks = [{net = "x.net.xml", begin = "soon"}]\nlocations = [{auto = 1}]\n', "networks[0].begin: must be a time"),
    ('networks = [{net = "x.net.xml", begin = -5}]\nlocations = [{auto = 1}]\n', "networks[0].begin: must be a time"),
])
def test_bad_spec_names_file_and_key(body, message, tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(SpecError, match=None) as e:
        load_spec(str(path)).scenarios()
    assert str(e.value).startswith(str(path)) and message in str(e.value) and "\n" not in str(e.value)
    code, _, err = _main(["--spec", str(path), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and err.count("\n") == 1 and message in err
    assert not (tmp_path / "o").exists()


def test_a_network_sumo_refuses_stops_the_sweep_before_any_work(cross_net, tmp_path, capsys):
    junk = tmp_path / "junk.net.xml"
    junk.write_text("<net>")
    spec = tmp_path / "two.json"
    spec.write_text(json.dumps({"networks": [cross_net, str(junk)], "locations": [{"center": [0, 0]}],
                                "p_mask": [0.5], "seeds": [3], "steps": 4, "rollout": 1.0}))
    code, stdout, err = _main(["--spec", str(spec), "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and err.count("\n") == 1 and "network 'junk'" in err and "junk.net.xml" in err, err
    assert not (tmp_path / "out").exists()


def test_sweep_index_pictures_and_a_failing_network(cross_net, tmp_path, capsys):
    from .conftest import netconvert
    # stock SUMO runs a railway (the preflight passes it); the model has no car lane to seed on it
    rail = netconvert('<node id="a" x="0" y="0"/><node id="b" x="300" y="0"/>',
                      '<edge id="ab" from="a" to="b" numLanes="1" speed="30" allow="rail"/>',
                      str(tmp_path / "rail.net.xml"))
    spec = tmp_path / "two.json"
    spec.write_text(json.dumps({"networks": [cross_net, rail], "locations": [{"center": [0, 0]}],
                                "p_mask": [0.5], "seeds": [3], "steps": 4, "rollout": 1.0}))
    out = tmp_path / "out"
    code, stdout, err = _main(["--spec", str(spec), "--out", str(out)], capsys)
    assert code == 1, err                                 # one entry failed, the rest went on
    rows = _index(out)
    assert [r["status"] for r in rows] == ["ok", "failed"]
    assert "rail.net.xml" in rows[1]["error"] and "failed s0001" in stdout
    assert sorted(os.listdir(out / "s0000")) == sorted(["scene.json", "scenario.rou.xml", "scenario.sumocfg",
                                                        "state.xml.gz", "rollout.json", "scene.png",
                                                        "cross.net.xml.gz"])   # the folder replays alone
    assert os.path.getsize(out / "contact_sheet.png") > 1000 and os.path.getsize(out / "stats.png") > 1000
    assert open(out / "index.csv").read().count("\n") == 3
    code, _, err = _main(["--spec", str(spec), "--out", str(out)], capsys)   # not without --resume
    assert code == 2 and "--resume" in err


@pytest.fixture(scope="module")
def reference(spec_file, tmp_path_factory):
    """An uninterrupted sweep on 2 one-thread workers (float results depend on the thread count)."""
    out = str(tmp_path_factory.mktemp("ref") / "out")
    assert main(get_options(["--spec", spec_file, "--out", out, "--no-pictures", "--workers", "2"])) == 0
    return _index(out)


def test_resume_after_sigkill_equals_uninterrupted(spec_file, reference, tmp_path):
    out = str(tmp_path / "killed")
    cmd = [sys.executable, "-m", "sumo_scendiff.sweep", "--spec", spec_file, "--out", out, "--workers", "2",
           "--no-pictures"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        done = [d for d in (os.listdir(out) if os.path.isdir(out) else []) if d.startswith("s") and
                ".partial" not in d and d != "sweep.json"]
        if len(done) >= 3:
            break
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)      # the parent only: its workers must die with it
    proc.wait()
    time.sleep(1.0)
    finished = [d for d in os.listdir(out) if d.startswith("s0") and ".partial" not in d]
    assert 0 < len(finished) < 16, finished
    res = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    assert f"{len(finished)} done before" in res.stderr
    assert _index(out) == reference
    assert not [d for d in os.listdir(out) if ".partial" in d or d == LOCK]


def test_ray_engine_on_a_local_instance(spec_file, reference, tmp_path, capsys):
    pytest.importorskip("ray")
    out = str(tmp_path / "ray")
    code, _, err = _main(["--spec", spec_file, "--out", out, "--engine", "ray", "--workers", "1",
                          "--no-pictures"], capsys)
    assert code == 0, err
    assert _index(out) == reference


# ---- the density axis in the worker -------------------------------------------------------------
ROUTES = ('<routes><flow id="f" begin="0" end="400" period="3" from="wc" to="ce"/>'
          '<flow id="g" begin="0" end="400" period="5" from="sc" to="cn"/></routes>')


def _levels_spec(tmp_path, cross_net, levels: str, routes: bool = True):
    rou = tmp_path / "r.rou.xml"
    rou.write_text(ROUTES)
    net = f'{{net = "{cross_net}", routes = "{rou}", begin = 60}}' if routes else f'"{cross_net}"'
    path = tmp_path / "levels.toml"
    path.write_text(f'networks = [{net}]\nlocations = [{{center = [0.0, 0.0]}}]\np_mask = [1.0]\n'
                    f'seeds = 1\nsteps = 4\nrollout = 1.0\n{levels}\n')
    return load_spec(str(path))


def test_the_target_of_a_scenario(cross_net, tmp_path):
    """Numbers pass, vehicles become a density over the window's car lanes, "auto" is the host
    simulation's level around the window (or the prior without one); a model without the condition
    refuses every target that is a number."""
    import libsumo

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.density import host_density
    from sumo_scendiff.sweep.worker import DensityUnsupported, scenario_target
    spec = _levels_spec(tmp_path, cross_net, 'density = [25, "auto"]')
    num, auto = spec.scenarios()
    (veh,) = _levels_spec(tmp_path, cross_net, "vehicles = [6]").scenarios()
    (none,) = _levels_spec(tmp_path, cross_net, "").scenarios()
    net, w = Network.load(cross_net), Window(0.0, 0.0, 0.0)
    assert scenario_target(num, net, w) == 25.0
    assert scenario_target(veh, net, w) == pytest.approx(6 / net.car_lane_km(w))
    assert scenario_target(auto, net, w) is None and scenario_target(none, net, w) is None
    assert scenario_target(auto, net, w, has_density=False) is None     # the prior: any model
    with pytest.raises(DensityUnsupported, match="^density = 25.0: my.pt has no density condition"):
        scenario_target(num, net, w, checkpoint="my.pt", has_density=False)
    with pytest.raises(DensityUnsupported, match="^vehicles = 6: the shipped model"):
        scenario_target(veh, net, w, has_density=False)
    libsumo.start([sumo_binary(), "-n", cross_net, "-r", str(tmp_path / "r.rou.xml"), "--no-step-log", "true"])
    try:
        for _ in range(60):
            libsumo.simulationStep()
        got = scenario_target(auto, net, w, sim=libsumo)
        assert got is not None and got > 0 and got == pytest.approx(host_density(libsumo, net, w))
        assert scenario_target(num, net, w, sim=libsumo) == 25.0        # a number is the number
    finally:
        libsumo.close()


class _NoDensity:
    """A generator without the density condition that must not be called."""
    has_density = False

    def generate(self, *a, **k):
        raise AssertionError("generate called for scenarios that should have failed")


def test_density_on_a_model_without_it_fails_each_scenario(cross_net, tmp_path):
    """Each scenario with a target fails with one clear line in its failure record and the index;
    nothing crashes and the model is never asked."""
    from sumo_scendiff.sweep.index import write_index
    from sumo_scendiff.sweep.worker import Worker, failure_path
    spec = _levels_spec(tmp_path, cross_net, 'density = [10, "auto"]')   # with routes: auto is a number too
    sc = spec.scenarios()
    out = str(tmp_path / "out")
    os.makedirs(out)
    w = Worker(spec, out, checkpoint="old.pt", generator=_NoDensity())
    try:
        assert w.run(sc) == [s.id for s in sc]
    finally:
        w.close()
    rows = write_index(out, sc)
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert [r["density"] for r in rows] == [10.0, "auto"]
    assert rows[0]["error"].startswith("density = 10.0: old.pt has no density condition")
    assert rows[1]["error"].startswith("density = 'auto' (") and "old.pt has no density condition" in rows[1]["error"]
    with open(failure_path(out, "s0001")) as f:
        rec = json.load(f)
    assert rec["status"] == "failed" and rec["vehicles"] is None and "\n" not in rec["error"]


class _Recording:
    """The shipped generator, claiming the density condition and recording the targets asked for
    (the scenes themselves come from the model's prior: the worker's plumbing is under test)."""
    def __init__(self, gen):
        self.gen, self.asked = gen, []

    has_density = True

    def __getattr__(self, name):
        return getattr(self.gen, name)

    def generate(self, *a, density=None, **k):
        self.asked.append(density)
        return self.gen.generate(*a, **k, density=density if self.gen.has_density else None)


def test_the_worker_passes_and_records_the_targets(cross_net, tmp_path):
    from sumo_scendiff.generation.generator import ScenarioGenerator
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sweep.index import COLUMNS, density_axis, stats_plot, write_index
    from sumo_scendiff.sweep.worker import Worker
    spec = _levels_spec(tmp_path, cross_net, 'density = [40, "auto"]')
    sc = spec.scenarios()
    out = str(tmp_path / "out")
    os.makedirs(out)
    gen = _Recording(ScenarioGenerator.load(None))
    w = Worker(spec, out, generator=gen)
    try:
        w.run(sc)
    finally:
        w.close()
    (asked,) = gen.asked                                   # one batched call, one target per scenario
    assert asked[0] == 40.0 and asked[1] is not None and asked[1] > 0
    rows = write_index(out, sc)
    assert [r["status"] for r in rows] == ["ok", "ok"], rows
    km = Network.load(cross_net).car_lane_km(w.window(spec.networks["cross"], "0,0")[0])
    for s, r, target in zip(sc, rows, asked):
        with open(os.path.join(out, s.id, "scene.json")) as f:
            block = json.load(f)["sweep"]
        assert block["density"] == s.density and block["density_target_veh_per_km"] == target
        assert block["car_lane_km"] == pytest.approx(km, abs=1e-3)
        assert r["density_target_veh_per_km"] == target and r["density"] == s.density
        assert r["vehicles_in_window"] == r["existing_vehicles"] + r["placed"]
        assert r["density_veh_per_km"] == pytest.approx(r["vehicles_in_window"] / km, abs=0.02)
    assert {"density", "vehicles", "density_target_veh_per_km", "density_veh_per_km"} <= set(COLUMNS)
    with open(os.path.join(out, "index.csv")) as f:
        assert "density_target_veh_per_km" in f.readline()
    assert density_axis(rows) and os.path.getsize(stats_plot(out, rows)) > 1000


def test_a_level_is_counted_as_run_counts_it(cross_net, tmp_path):
    """A density (a number, "auto", the host's default) is kept as SUMO's edgeData counts it, a
    vehicle count one vehicle at a time (sim.request.counted_as_asked, as run and the co-simulation
    API); the two never share a model call."""
    from sumo_scendiff.sweep.engines import tasks
    dens = _levels_spec(tmp_path, cross_net, 'density = [25, "auto"]').scenarios()
    (veh,) = _levels_spec(tmp_path, cross_net, "vehicles = [6]").scenarios()
    (none,) = _levels_spec(tmp_path, cross_net, "").scenarios()
    assert [s.generation.count_on_edges for s in [*dens, veh, none]] == [True, True, False, True]
    import dataclasses
    mixed = [dataclasses.replace(s, id=f"s{k:04d}") for k, s in enumerate([dens[0], veh] * 5)]
    batches = [b for b, _ in tasks(mixed)]
    assert max(map(len, batches)) == 2 and sum(map(len, batches)) == 10
    assert all(len({s.generation.count_on_edges for s in b}) == 1 for b in batches)
