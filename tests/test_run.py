"""`python -m sumo_scendiff.run`: the shipped model, real libsumo, export; bad input -> one line, exit 2."""
from __future__ import annotations

import json
import os
import shutil

import pytest

from sumo_scendiff import run as run_cli
from sumo_scendiff.sim.seed_report import STATUSES

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

TOKENS = """p_mask = 0.6
[[agents]]
x = 20.0
y = -1.6
heading = 0.0
speed = 8.0
"""


def _run(args, capsys):
    try:
        code = run_cli.main(run_cli.get_options(args))
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def demand(cross_net, tmp_path_factory):
    path = tmp_path_factory.mktemp("demand") / "cross.rou.xml"
    vehicles = "".join(f'<vehicle id="v{k}" depart="{2 * k}"><route edges="wc ce"/></vehicle>'
                       f'<vehicle id="n{k}" depart="{2 * k + 1}"><route edges="sc cn"/></vehicle>'
                       for k in range(10))
    path.write_text(f"<routes>{vehicles}</routes>")
    return str(path)


def test_run_center_tokens_and_rollout(cross_net, tmp_path, capsys):
    tok = tmp_path / "tokens.toml"
    tok.write_text(TOKENS)
    out = tmp_path / "out"
    common = ["-n", cross_net, "--center", "0,0", "--tokens", str(tok), "--scenes", "2",
              "--rollout", "4", "-s", "5", "--steps", "8"]
    args = common + ["-o", str(out)]
    code, stdout, err = _run(args, capsys)
    assert code == 0, err
    assert sorted(os.listdir(out)) == ["run.json", "scene_000", "scene_001"]
    summary = json.load(open(out / "run.json"))
    assert [s["scene"] for s in summary["scenes"]] == ["scene_000", "scene_001"]
    assert set(summary["timing_s"]) == {"load", "raster", "generate", "seed", "rollout", "export"}
    doc = json.load(open(out / "scene_000" / "scene.json"))
    assert doc["window"] == {"cx": 0.0, "cy": 0.0, "yaw": 0.0, "size": 100.0}
    assert doc["p_mask"] == 0.6 and doc["tokens"][0]["x"] == 20.0 and doc["tokens"][0]["source"] == "user"
    assert doc["model"]["pin_tokens"] and not doc["tokens"][0]["pinned"]   # no size: a condition only
    assert doc["model"]["lane_headings"] and doc["model"]["lane_snap"] and doc["model"]["pin_speeds"]
    assert len(doc["model"]["sha256"]) == 64 and doc["model"]["sampler"] == "sample_dpmpp_2m"
    for a in doc["agents"]:
        assert abs(a["x"]) <= 50 and abs(a["y"]) <= 50 and len(a["poses"]) == 5
        assert a["status"] in STATUSES
    roll = json.load(open(out / "scene_000" / "rollout.json"))
    assert roll["seconds"] == 4.0 and sum(roll[s] for s in STATUSES) == roll["generated"]
    assert "placed" in stdout and "scene_001" in stdout

    # the same seed gives the same scenes
    code, _, err = _run(common + ["-o", str(tmp_path / "again")], capsys)
    assert code == 0, err
    again = json.load(open(tmp_path / "again" / "scene_000" / "scene.json"))
    assert [a["poses"] for a in again["agents"]] == [a["poses"] for a in doc["agents"]]
    assert json.load(open(tmp_path / "again" / "scene_001" / "rollout.json")) == \
        json.load(open(out / "scene_001" / "rollout.json"))

    # a second run into the same folder is refused, nothing is touched
    before = (out / "scene_000" / "scene.json").read_bytes()
    code, _, err = _run(args, capsys)
    assert code == 2 and "exists" in err and err.count("\n") == 1
    assert (out / "scene_000" / "scene.json").read_bytes() == before


def test_run_ego_infill(cross_net, demand, tmp_path, capsys):
    out = tmp_path / "ego"
    code, _, err = _run(["-n", cross_net, "-r", demand, "--ego", "v3", "--scenes", "1", "--rollout", "2",
                         "-o", str(out), "--steps", "8"], capsys)
    assert code == 0, err
    doc = json.load(open(out / "scene_000" / "scene.json"))
    sources = [t["source"] for t in doc["tokens"]]
    assert "v3" in sources                      # the ego itself is a token: the model fills around it
    assert all(t["pinned"] for t in doc["tokens"])  # existing vehicles: pose, size, speed -> pinned
    assert abs(doc["window"]["yaw"]) < 0.05     # the ego drives east: the window turns with it
    ids = {a["vehicle"] for a in doc["agents"]}
    assert not ids & {"v3"}                     # existing vehicles are kept, never re-seeded


@pytest.mark.parametrize("case, expect", [
    ("missing-net", "no such file"),
    ("not-a-net", "junk.net.xml: SUMO refuses to load it: Invalid network"),   # stock SUMO's words
    ("far-center", "off the network"),
    ("bad-tokens", "agents[0]"),
    ("ego-never", "never appears"),
    ("unwritable", "not writable"),
    ("foreign-routes", "SUMO refuses to load it: The edge 'x' within the route for vehicle 'a' is not known"),
])
def test_bad_input_one_line_exit_2(case, expect, cross_net, demand, tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[[agents]]\nx = 10\ny = 0\nspeed = -3\n')
    junk = tmp_path / "junk.net.xml"
    junk.write_text("<routes/>")
    (tmp_path / "file").write_text("x")
    foreign = tmp_path / "foreign.rou.xml"
    foreign.write_text('<routes><vehicle id="a" depart="0"><route edges="x y"/></vehicle></routes>')
    args = {"missing-net": ["-n", str(tmp_path / "nope.net.xml")],
            "not-a-net": ["-n", str(junk)],
            "far-center": ["-n", cross_net, "--center", "5000,5000"],
            "bad-tokens": ["-n", cross_net, "--center", "0,0", "--tokens", str(bad)],
            "ego-never": ["-n", cross_net, "-r", demand, "--ego", "nobody"],
            "unwritable": ["-n", cross_net, "--center", "0,0", "-o", str(tmp_path / "file" / "sub")],
            "foreign-routes": ["-n", cross_net, "-r", str(foreign), "--center", "0,0"],
            }[case]
    out = tmp_path / "out"
    code, _, err = _run(args + (["-o", str(out)] if "-o" not in args else []) + ["--rollout", "0"], capsys)
    assert code == 2
    assert err.count("\n") == 1 and expect in err and "Traceback" not in err
    assert not (out / "scene_000").exists() and not (out / "run.json").exists()


@pytest.mark.parametrize("flag, value, expect", [("--step-length", "0", "--step-length must be > 0"),
                                                  ("--lateral-resolution", "-0.5", "--lateral-resolution must be >= 0")])
def test_sumo_settings_are_checked(flag, value, expect, cross_net, tmp_path, capsys):
    code, _, err = _run(["-n", cross_net, "--center", "0,0", flag, value, "-o", str(tmp_path / "o")], capsys)
    assert code == 2 and expect in err.splitlines()[-1] and not (tmp_path / "o").exists()


def test_the_sumo_settings_flags_reach_the_configuration(cross_net):
    o = run_cli.get_options(["-n", cross_net, "--lateral-resolution", "0.4", "--no-seeding-options"])
    assert o.lateral_resolution == 0.4 and o.seeding_options is False and o.step_length is None
    assert run_cli.get_options(["-n", cross_net]).seeding_options is True


def test_negative_guidance_is_a_usage_error(cross_net, tmp_path, capsys):
    code, _, err = _run(["-n", cross_net, "--center", "0,0", "--guidance", "-1", "-o", str(tmp_path / "o")], capsys)
    assert code == 2 and "--guidance: must be >= 0" in err and not (tmp_path / "o").exists()


@pytest.mark.parametrize("begin", ["-5", "nan", "inf", "0:08:00"])
def test_a_begin_is_a_time_at_or_after_zero(cross_net, tmp_path, capsys, begin):
    """--begin is read as SUMO reads a time (s or H:M:S; "0:08:00" is 8 minutes, a valid time the
    demandless run accepts); a negative, NaN or infinite one stops in the argument parser."""
    args = ["-n", cross_net, "--center", "0,0", "--begin", begin, "--rollout", "0", "--steps", "2",
            "-o", str(tmp_path / "o")]
    if begin == "0:08:00":
        assert run_cli.get_options(args).begin == 480.0
        return
    code, _, err = _run(args, capsys)
    assert code == 2 and "--begin" in err and not (tmp_path / "o").exists()
    assert ("not a time" if begin == "nan" else "a time must be >= 0") in err   # NaN is no time SUMO reads


def test_cli_defaults_are_the_generators():
    from sumo_scendiff.generation.generator import GenerationConfig
    o = run_cli.get_options(["-n", "x.net.xml"])
    assert (o.steps, o.guidance, o.threshold) == (GenerationConfig().steps, GenerationConfig().guidance,
                                                  GenerationConfig().threshold)


def test_resume_writes_only_the_missing_scenes(cross_net, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["-n", cross_net, "--center", "0,0", "--scenes", "3", "--rollout", "2", "-s", "3", "--steps", "4",
            "-o", str(out)]
    code, _, err = _run(args, capsys)
    assert code == 0, err
    whole = {k: (out / f"scene_{k:03d}" / "scene.json").read_bytes() for k in range(3)}
    rows = json.loads((out / "run.json").read_text())["scenes"]
    # an interrupted run: scene_001 never completed, its writer died half-way, no run.json
    shutil.rmtree(out / "scene_001")
    os.remove(out / "run.json")
    (out / "scene_001.partial-999999999").mkdir()
    (out / "scene_000" / "kept").write_text("")
    code, _, err = _run(args + ["--resume"], capsys)
    assert code == 0, err
    assert (out / "scene_000" / "kept").exists()              # complete scenes are not written again
    assert {k: (out / f"scene_{k:03d}" / "scene.json").read_bytes() for k in range(3)} == whole
    assert json.loads((out / "run.json").read_text())["scenes"] == rows
    assert sorted(os.listdir(out)) == ["run.json", "scene_000", "scene_001", "scene_002"]

    code, _, err = _run(args + ["--resume", "--force"], capsys)
    assert code == 2 and "not allowed with" in err.splitlines()[-1]
    code, _, err = _run(args + ["--resume", "-s", "4"], capsys)     # not this run's scenes: refused
    assert code == 2 and err.count("\n") == 1 and "scene_000: written by another command" in err
    assert {k: (out / f"scene_{k:03d}" / "scene.json").read_bytes() for k in range(3)} == whole
