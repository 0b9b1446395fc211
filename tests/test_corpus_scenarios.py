"""The committed subset of the public scenario corpus (tests/data/corpus: SUMO's own tools/game scenarios,
EPL-2.0) and the feature variants run as a new user would -- stock SUMO, run -c, fill -c, and the exported
folders replayed in stock SUMO (benchmarks/scenarios.py's steps; its harness: test_corpus.py)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

from tests.corpus_support import STATUSES, copy_scenario as _copy, entry as _entry, load_corpus


@pytest.fixture(scope="module")
def corpus():
    return load_corpus()


# The committed subset through the product. Each configuration names additional files whose root is <add>
# (a TLS program, timed events and edgeData outputs), which the product refused before it read inputs as SUMO
# does.
SUBSET = [
    pytest.param("game_square", id="square"),
    pytest.param("game_cross", id="cross-add-root"),
    pytest.param("game_ramp", id="ramp-highway-add-root"),
    pytest.param("sumotest_containers_bidi", id="sumo-test-containers-bidi-straight-road"),
]


@pytest.mark.slow
@pytest.mark.parametrize("name", SUBSET)
def test_committed_scenario_runs_fills_and_replays_in_stock_sumo(corpus, tmp_path, name):
    sc = _entry(corpus, name)
    cfg = _copy(name, tmp_path, corpus)
    t, area = corpus.begin_time(sc, cfg), corpus.fill_area(sc, cfg, side=200.0)
    out = tmp_path / "out"
    for step, cmd in corpus.commands(cfg, t, area, out, scenes=1, rollout=5).items():
        res = corpus.check_count(step, corpus.step(cmd, corpus.TIMEOUT[step], out / "logs" / f"{step}.log", tmp_path),
                                 out)
        assert res["ok"], f"{step}: {res.get('error')}  ({res['cmd']})"
        assert step not in ("run_replay", "fill_replay", "fill_start") or "vehicles" in res, step
    for doc in (out / "run" / "scene_000" / "scene.json", out / "fill" / "fill.json"):
        counts = corpus.placement(doc)
        assert counts is not None and set(counts) - {"agents", "placed_share"} <= STATUSES, counts


@pytest.mark.slow
def test_a_scenario_stock_sumo_refuses_is_one_line_with_sumos_error(corpus, tmp_path):
    """As tools/game/bs3d.sumocfg: an option this SUMO does not know, outside <gui_only>."""
    cfg = _copy("game_square", tmp_path, corpus)
    cfg.write_text(cfg.read_text().replace("<report>", '<report>\n        <osg-view value="true"/>'))
    ref = subprocess.run([corpus._sumo(), "-c", str(cfg)], capture_output=True, text=True)
    assert ref.returncode != 0 and "osg-view" in ref.stderr
    for tool in ("run", "fill"):
        p = subprocess.run([sys.executable, "-m", f"sumo_scendiff.{tool}", "-c", str(cfg), "--begin", "60",
                            "-o", str(tmp_path / tool)], capture_output=True, text=True, cwd=tmp_path)
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert p.returncode == 2 and len(lines) == 1 and "osg-view" in lines[0], p.stderr[-500:]
        assert not (tmp_path / tool).exists()


@pytest.mark.slow
def test_begin_while_a_flow_is_still_being_inserted(corpus, tmp_path):
    """As sumo-rl's 4x4loop and SUMO's manhattan tutorial: a flow of many vehicles from 0 to 0 s, which SUMO
    inserts one after another for minutes; stock SUMO has vehicles on the road at T."""
    netgen = shutil.which("netgenerate") or str(corpus._sumo_home() / "bin" / "netgenerate")
    subprocess.run([netgen, "--grid", "--grid.number", "4", "--grid.length", "200", "-o", "net.net.xml"],
                   cwd=tmp_path, check=True, capture_output=True)
    (tmp_path / "r.rou.xml").write_text('<routes><flow id="f" begin="0" end="0" number="150" from="A0B0" '
                                        'to="C0D0" departSpeed="max"/></routes>')
    cfg = tmp_path / "s.sumocfg"
    cfg.write_text('<configuration><input><net-file value="net.net.xml"/><route-files value="r.rou.xml"/>'
                   '</input></configuration>')
    out = tmp_path / "out"
    ref = corpus.step(corpus.commands(cfg, 120, (0, 0, 1, 1), out)["sumo"], 120, out / "sumo.log", tmp_path)
    assert ref["ok"] and corpus.running_at(out / "sumo_summary.xml", 120) > 0
    p = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-c", str(cfg), "--begin", "120", "--scenes", "1",
                        "--rollout", "5", "-o", str(out / "run")], capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-300:]


@pytest.mark.slow
def test_a_network_without_car_lanes_finishes_with_nothing_to_generate(corpus, tmp_path):
    """SUMO's railway game (trains, stops, rerouters; no lane a car may use): stock SUMO runs it, and so
    do run -c and fill -c, each exit 0 with one notice, a record saying why and no scene to replay."""
    sc = _entry(corpus, "game_rail")
    cfg = _copy("game_rail", tmp_path, corpus)
    t = corpus.begin_time(sc, cfg)
    out = tmp_path / "out"
    steps = corpus.commands(cfg, t, (0.0, 0.0, 400.0, 400.0), out, scenes=1, rollout=5)
    for step in ("sumo", "run", "fill"):
        res = corpus.step(steps[step], corpus.TIMEOUT[step], out / "logs" / f"{step}.log", tmp_path)
        assert res["ok"], f"{step}: {res.get('error')}"
    run = json.loads((out / "run" / "run.json").read_text())
    assert run["scenes"] == [] and "no car lane" in json.dumps(run)
    assert "no car lane" in (out / "fill" / "fill.json").read_text()
    assert not (out / "run" / "scene_000").exists() and not (out / "fill" / "state.xml.gz").exists()


def test_the_scenarios_car_following_model_travels_with_the_seeded_vehicles(corpus, tmp_path):
    """A seeded vehicle copies one of the scenario's vTypes; the portable start writes that definition
    (here IDM with its delta), not only the Krauss parameters TraCI can read back."""
    cfg = _copy("game_cross", tmp_path, corpus)
    routes = cfg.parent / "cross" / "cross.rou.xml"
    routes.write_text(routes.read_text().replace('<vType id="passenger" ',
                                                 '<vType id="passenger" carFollowModel="IDM" delta="3.5" '))
    out = tmp_path / "fill"
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-c", str(cfg), "--begin", "60",
                           "-o", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    fill = json.loads((out / "fill.json").read_text())
    passenger = [a["vehicle"] for a in fill["agents"] if a.get("vtype") == "passenger" and a.get("vehicle")]
    assert passenger, "no vehicle was seeded as the scenario's passenger type"
    import xml.etree.ElementTree as ET
    start = ET.parse(out / "start.rou.xml").getroot()
    types = {t.get("id"): t for t in start.iter("vType")}
    for v in start.iter("vehicle"):
        if v.get("id") in passenger:
            t = types[v.get("type")]
            assert t.get("carFollowModel") == "IDM" and t.get("delta") == "3.5" and t.get("probability") is None
    ref = subprocess.run([corpus._sumo(), "-c", str(out / "start.sumocfg"), "--end", "70"],
                         capture_output=True, text=True)
    assert ref.returncode == 0 and "Error" not in ref.stderr, ref.stderr


def test_the_feature_matrix_is_one_generated_variant_per_feature(corpus):
    """The feature rows (benchmarks/scenarios_features.py): each a small generated grid plus one SUMO
    feature, built by the corpus's own build (source kind ``feature``), named for what it covers."""
    rows = [s for s in corpus.REGISTRY if s.get["kind"] == "feature"]
    assert len(rows) >= 14 and all(s.name.startswith("feat_") and s.licence == "generated" and s.covers
                                   for s in rows)
    covered = {c for s in rows for c in s.covers}
    assert {"mesoscopic", "sublane model", "parkingAreas", "TAZ", "trams", "electric vehicles",
            "calibrators", "gzip files", "triggered departure"} <= covered


@pytest.mark.slow
def test_every_feature_variant_runs_in_stock_sumo(corpus, tmp_path):
    """A variant stock SUMO refuses is a wrong variant, not a finding: each is built and run to T+30."""
    for sc in (s for s in corpus.REGISTRY if s.get["kind"] == "feature"):
        cfg = corpus.build(sc, tmp_path)
        assert json.loads((tmp_path / sc.name / "source.json").read_text())["get"]["feature"] == sc.name
        ref = subprocess.run([corpus._sumo(), "-c", str(cfg), "--end", f"{corpus.begin_time(sc, cfg) + 30:g}"],
                             capture_output=True, text=True, cwd=tmp_path)   # a calibrator writes there
        assert ref.returncode == 0 and "Error" not in ref.stderr, f"{sc.name}: {ref.stderr[-300:]}"
