"""Sweeps: spec validation, the index, a network failing in one entry, resume after SIGKILL, Ray."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from sumo_scendiff.sweep.__main__ import get_options, main
from sumo_scendiff.sweep.spec import SpecError, load_spec

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


def test_sweep_index_pictures_and_a_failing_network(cross_net, tmp_path, capsys):
    junk = tmp_path / "junk.net.xml"
    junk.write_text("<net>")
    spec = tmp_path / "two.json"
    spec.write_text(json.dumps({"networks": [cross_net, str(junk)], "locations": [{"center": [0, 0]}],
                                "p_mask": [0.5], "seeds": [3], "steps": 4, "rollout": 1.0}))
    out = tmp_path / "out"
    code, stdout, err = _main(["--spec", str(spec), "--out", str(out)], capsys)
    assert code == 1, err                                 # one entry failed, the rest went on
    rows = _index(out)
    assert [r["status"] for r in rows] == ["ok", "failed"]
    assert "junk.net.xml" in rows[1]["error"] and "failed s0001" in stdout
    assert sorted(os.listdir(out / "s0000")) == sorted(["scene.json", "scenario.rou.xml", "scenario.sumocfg",
                                                        "state.xml.gz", "rollout.json", "scene.png"])
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
                not d.endswith(".partial") and d != "sweep.json"]
        if len(done) >= 3:
            break
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)      # the parent only: its workers must die with it
    proc.wait()
    time.sleep(1.0)
    finished = [d for d in os.listdir(out) if d.startswith("s0") and not d.endswith(".partial")]
    assert 0 < len(finished) < 16, finished
    res = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    assert f"{len(finished)} done before" in res.stderr
    assert _index(out) == reference
    assert not [d for d in os.listdir(out) if d.endswith(".partial")]


def test_ray_engine_on_a_local_instance(spec_file, reference, tmp_path, capsys):
    pytest.importorskip("ray")
    out = str(tmp_path / "ray")
    code, _, err = _main(["--spec", spec_file, "--out", out, "--engine", "ray", "--workers", "1",
                          "--no-pictures"], capsys)
    assert code == 0, err
    assert _index(out) == reference
