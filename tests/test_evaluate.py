"""The evaluation CLI end to end on a tiny network (baselines; the model rows are covered by the
end-to-end test's generator)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

CLI = [sys.executable, "-m", "sumo_scendiff.evaluate"]


@pytest.fixture(scope="module")
def pool(tmp_path_factory, cross_net):
    """Random Log's training pool: 30 scenes recorded on ``cross_net`` by the data CLI, once."""
    pool = tmp_path_factory.mktemp("eval") / "pool"
    assert subprocess.run([sys.executable, "-m", "sumo_scendiff.data", "-n", cross_net, "-o", str(pool),
                           "--scenes", "30", "-s", "9"], capture_output=True).returncode == 0
    return pool


def test_evaluate_prints_the_table_and_json(tmp_path, cross_net, pool):
    out = tmp_path / "r.json"
    res = subprocess.run(CLI + ["-n", cross_net, "--scenes", "30", "--no-model", "--train-data", str(pool),
                                "--cache", str(tmp_path / "cache"), "--json", str(out)],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0].startswith("| networks | method | MMD² pos")  # the summary first
    start = next(i for i, ln in enumerate(lines) if ln.startswith("| network | method | MMD² pos"))
    end = lines.index("", start)
    names = [ln.split("|")[2].strip() for ln in lines[start + 2:end]]
    assert names == ["Ground truth", "SUMO 2 min later", "Random Log", "Lane-uniform",
                     "Lane-uniform (true count)"]
    # Scenario Dreamer's JSD set after it, SUMO's traffic in the other windows as its floor
    jsd_names = [ln.split("|")[2].strip() for ln in lines[end + 4:]]
    assert jsd_names == ["SUMO, other windows"] + names[1:]
    rows = json.loads(out.read_text())["distribution"][0]["methods"]
    assert rows["Ground truth"]["traj_on_drivable"] > 0.95
    # the same windows later in SUMO: on the road and nearer the ground truth than Random Log
    assert rows["SUMO 2 min later"]["traj_on_drivable"] > 0.95
    assert rows["SUMO 2 min later"]["mmd2_joint"] < rows["Random Log"]["mmd2_joint"]
    assert rows["Random Log"]["traj_on_drivable"] < rows["Ground truth"]["traj_on_drivable"]
    assert rows["Lane-uniform (true count)"]["agents_emd"] < 0.5
    jsd = json.loads(out.read_text())["distribution"][0]["jsd"]
    # Random Log's fleet and lanes come from other networks; Lane-uniform puts every box on a centre line
    assert jsd["Random Log"]["jsd_lane_distance"] > jsd["SUMO, other windows"]["jsd_lane_distance"]
    assert 0 <= jsd["SUMO, other windows"]["jsd_speed"] < jsd["Lane-uniform"]["jsd_speed"]


def test_evaluate_bad_network(tmp_path):
    bad = tmp_path / "bad.net.xml"
    bad.write_text("<nonsense/>")
    res = subprocess.run(CLI + ["-n", str(bad), "--no-model", "--cache", str(tmp_path / "c")],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "bad.net.xml" in res.stderr and "Traceback" not in res.stderr


def test_evaluate_bad_settings_exit_2(tmp_path):
    for bad in (["--sampler", "rk4"], ["--scene-guidance-sigma", "-1"], ["--tokens"]):
        res = subprocess.run(CLI + ["--no-model", "--cache", str(tmp_path / "c")] + bad,
                             capture_output=True, text=True)
        assert res.returncode == 2 and bad[0] in res.stderr and "Traceback" not in res.stderr


def test_evaluate_tokens_prints_the_three_token_tables_with_progress(tmp_path, cross_net, pool):
    out = tmp_path / "r.json"
    # the 14 generation runs over --token-scenes windows are the cost: two windows hold four tokens
    res = subprocess.run(CLI + ["-n", cross_net, "--scenes", "4", "--tokens", "--token-scenes", "2",
                                "--train-data", str(pool), "--cache", str(tmp_path / "cache"),
                                "--json", str(out)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert "token tables, " in res.stderr and "14/14" in res.stderr   # the bar over the 14 runs
    assert "evaluating " in res.stderr
    assert "token mask probability (table 2)" in res.stdout
    tables = next(iter(json.loads(out.read_text())["tokens"].values()))
    assert [r["p_mask"] for r in tables["mask"]] == [0.0, 0.1, 0.3, 0.5, 0.7, 0.9]
    assert [r["threshold"] for r in tables["threshold"]] == [0.5, 0.6, 0.7, 0.8, 0.9]
    assert [r["features"] for r in tables["speed"]] == ["pose + extents", "+ speed", "+ speed + final speed"]
    # the shipped model places the pinned tokens of the recorded crossing
    assert tables["mask"][0]["match_rate"] > 0.8


def test_pictures_are_one_complete_png(cross_net, cross_scene, tmp_path):
    import cv2

    from sumo_scendiff.evaluate.__main__ import save_pictures
    from sumo_scendiff.map.network import Network
    net = Network.load(cross_net)
    scene = cross_scene(net)
    path = tmp_path / "pics" / "cross.png"
    save_pictures(net, {"Ground truth": [scene], "Model": [scene]}, str(path))
    img = cv2.imread(str(path))
    assert img is not None and img.shape[1] > img.shape[0] > 0     # two tiles side by side
    assert [p.name for p in path.parent.iterdir()] == ["cross.png"]
