"""The public scenario corpus's harness (benchmarks/scenarios.py): its registry and cache, its build, its
steps and the replays' counts. The committed scenarios run through the product: test_corpus_scenarios.py."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.corpus_support import HERE, entry as _entry, load_corpus


@pytest.fixture(scope="module")
def corpus():
    return load_corpus()


def test_registry_is_public_and_covers_the_kinds_of_traffic(corpus):
    names = [s.name for s in corpus.REGISTRY]
    assert len(names) >= 25 and len(set(names)) == len(names)
    assert all(s.licence and s.source and s.config for s in corpus.REGISTRY)
    assert not any("DLR-TS/sumo-scenarios" in json.dumps(s.get) for s in corpus.REGISTRY)
    covered = {c for s in corpus.REGISTRY for c in s.covers}
    assert {"left-hand", "bicycles", "pedestrians", "buses", "actuated lights", "roundabouts",
            "highway", "rail", "trams", "persons", "rerouters"} <= {c for s in corpus.REGISTRY
                                                                   if s.get["kind"] != "feature" for c in s.covers}


def test_every_wheel_scenario_is_in_the_installed_sumo(corpus):
    home = corpus._sumo_home()
    for s in corpus.REGISTRY:
        if s.get["kind"] == "sumo-wheel":
            assert (home / s.get["path"]).is_file(), s.name


def test_build_copies_every_named_file_and_records_its_source(corpus, tmp_path):
    cfg = corpus.build(_entry(corpus, "game_cross"), tmp_path)
    assert cfg == tmp_path / "game_cross" / "cross.sumocfg"
    for rel in corpus._named_files(cfg):
        assert (cfg.parent / rel).is_file(), rel
    record = json.loads((cfg.parent / "source.json").read_text())
    assert record["get"] == {"kind": "sumo-wheel", "path": "tools/game/cross.sumocfg"}
    assert record["licence"] == "EPL-2.0" and record["eclipse-sumo"]
    assert not list(tmp_path.glob("*.partial"))
    ref = subprocess.run([corpus._sumo(), "-c", str(cfg), "--end", "10"], capture_output=True, text=True)
    assert ref.returncode == 0, ref.stderr


def test_a_wheel_source_runs_its_build_steps_and_reads_sumos_option_synonyms(corpus, tmp_path):
    """sumolib's RiLSA example: its flows by its own makeRoutes.py; its configuration (root ``<c>``) names
    the network by SUMO's synonym ``net``, which the harness's area reads as SUMO does."""
    sc = _entry(corpus, "sumolib_rilsa1")
    cfg = corpus.build(sc, tmp_path)
    assert (cfg.parent / "flows.rou.xml").is_file() and (cfg.parent / "makeRoutes.py").is_file()
    x0, y0, x1, y1 = corpus.fill_area(sc, cfg)
    assert x1 > x0 and y1 > y0


def test_a_step_runs_the_product_of_this_work_tree(corpus, tmp_path):
    """Each row names the work tree's commit: its steps import the product from there, not from wherever an
    editable install of the package points (another checkout)."""
    code = "import sumo_scendiff; print(sumo_scendiff.__file__)"
    res = corpus.step([sys.executable, "-c", code], 60, tmp_path / "where.log", tmp_path)
    assert res["ok"]
    assert str(HERE.parent / "sumo_scendiff") in (tmp_path / "where.log").read_text()


def test_a_github_source_not_at_hand_is_named(corpus, tmp_path):
    sc = corpus.Scenario("x", "github:someone/nothing", "MIT",
                         {"kind": "github", "repo": "someone/nothing",
                          "files": {"x.sumocfg": ["x.sumocfg", "0" * 40]}, "steps": []}, "x.sumocfg")
    row = corpus.run_scenario(sc, tmp_path, tmp_path / "no-mirror")
    assert row["steps"]["build"]["ok"] is False and "someone/nothing" in row["steps"]["build"]["error"]
    assert corpus.first_failure(row)[0] == "build"


def test_a_github_source_runs_the_scripts_it_ships(corpus, tmp_path):
    """As SUMO's traci_tls tutorial: its demand is written by its own generateRoutes.py (the folder's
    script runs; a step naming a SUMO tool or binary runs that), and source.json names each file's commit."""
    commit = "1" * 40
    files = {"gen.py": "open('data/r.rou.xml', 'w').write('<routes><flow id=\"f\" begin=\"0\" end=\"60\" '\n"
                       "    'number=\"5\" from=\"A0A1\" to=\"A1B1\"/></routes>')\n",
             "data/s.sumocfg": '<configuration><input><net-file value="n.net.xml"/>'
                               '<route-files value="r.rou.xml"/></input></configuration>'}
    for rel, text in files.items():
        saved = tmp_path / "_github" / "someone+tut" / commit / "tut" / rel
        saved.parent.mkdir(parents=True, exist_ok=True)
        saved.write_text(text)
    sc = corpus.Scenario("tut", "github:someone/tut", "EPL-2.0",
                         {"kind": "github", "repo": "someone/tut",
                          "files": {rel: ["tut/" + rel, commit] for rel in files},
                          "steps": [["netgenerate", "--grid", "--grid.number", "2", "-o", "data/n.net.xml"],
                                    ["gen.py"]]}, "data/s.sumocfg")
    cfg = corpus.build(sc, tmp_path)
    assert (cfg.parent / "r.rou.xml").is_file()
    record = json.loads((tmp_path / "tut" / "source.json").read_text())
    assert record["get"]["files"]["gen.py"] == ["tut/gen.py", commit]
    ref = subprocess.run([corpus._sumo(), "-c", str(cfg), "--end", "30"], capture_output=True, text=True)
    assert ref.returncode == 0, ref.stderr


def test_the_fill_area_holds_car_lanes_where_the_centre_has_none(corpus, tmp_path):
    """As Hangzhou's 4x4 grid of 800 m blocks and SUMO's circular tutorial: the median of the junctions
    lies inside a block, and a 400 m square about it holds no lane (the fill refused it: "no car lane
    inside"); the square is then about the junction nearest that median."""
    netgen = shutil.which("netgenerate") or str(corpus._sumo_home() / "bin" / "netgenerate")
    subprocess.run([netgen, "--grid", "--grid.number", "2", "--grid.length", "1000", "-o", "net.net.xml"],
                   cwd=tmp_path, check=True, capture_output=True)
    (tmp_path / "s.sumocfg").write_text('<configuration><input><net-file value="net.net.xml"/></input>'
                                        '</configuration>')
    sc = corpus.Scenario("g", "generated", "-", {"kind": "generate"}, "s.sumocfg")
    x0, y0, x1, y1 = corpus.fill_area(sc, tmp_path / "s.sumocfg")
    assert (x1 - x0, y1 - y0) == (400.0, 400.0)     # the whole square: the corner's lanes lie beyond x0, y0
    assert any((x0 + x1) / 2 == x and (y0 + y1) / 2 == y for x in (0, 1000) for y in (0, 1000)), (x0, y0, x1, y1)


def test_the_fill_area_of_a_straight_road_has_a_width(corpus, tmp_path):
    """As SUMO's container test on one bidirectional edge: the network's boundary is a line (y0 == y1),
    and the square clipped to it had no height (the fill refused "--area: needs ... Y1 > Y0")."""
    netgen = shutil.which("netgenerate") or str(corpus._sumo_home() / "bin" / "netgenerate")
    subprocess.run([netgen, "--grid", "--grid.x-number", "3", "--grid.y-number", "1", "--grid.length", "500",
                    "-o", "net.net.xml"], cwd=tmp_path, check=True, capture_output=True)
    (tmp_path / "s.sumocfg").write_text('<configuration><input><net-file value="net.net.xml"/></input>'
                                        '</configuration>')
    sc = corpus.Scenario("g", "generated", "-", {"kind": "generate"}, "s.sumocfg")
    x0, y0, x1, y1 = corpus.fill_area(sc, tmp_path / "s.sumocfg")
    assert x1 - x0 == 400.0 and y1 - y0 == 400.0 and y0 < 0 < y1, (x0, y0, x1, y1)


def test_a_sumo_test_is_run_as_its_test_runner_joins_its_options(corpus, tmp_path):
    """A test of SUMO's suite has no configuration: its options.sumo files (tests/sumo's, then the test
    folder's) are its command line, which SUMO writes as the configuration stock sumo -c runs."""
    netgen = shutil.which("netgenerate") or str(corpus._sumo_home() / "bin" / "netgenerate")
    subprocess.run([netgen, "--grid", "--grid.number", "2", "-o", "net.net.xml"], cwd=tmp_path, check=True,
                   capture_output=True)
    (tmp_path / "input_routes.rou.xml").write_text('<routes><flow id="f" begin="0" end="60" number="5" '
                                                   'from="A0A1" to="A1B1"/></routes>')
    (tmp_path / "outer.sumo").write_text("--xml-validation never\n--default.speeddev 0\n")
    (tmp_path / "inner.sumo").write_text("--no-step-log --net-file=net.net.xml\n-r input_routes.rou.xml\n-t\n")
    import scenarios_build
    scenarios_build._test_config(tmp_path, "test.sumocfg", ["outer.sumo", "inner.sumo"])
    text = (tmp_path / "test.sumocfg").read_text()
    for option in ('<default.speeddev value="0"/>', '<net-file value="net.net.xml"/>',
                   '<route-files value="input_routes.rou.xml"/>', '<duration-log.statistics value="true"/>'):
        assert option in text
    ref = subprocess.run([corpus._sumo(), "-c", str(tmp_path / "test.sumocfg"), "--end", "30"],
                         capture_output=True, text=True)
    assert ref.returncode == 0, ref.stderr


def test_a_product_step_writing_beside_its_output_folder_fails(corpus, tmp_path):
    """run and fill write into their -o folder only: an SSM device's ssm_<vehicle>.xml, which SUMO writes
    where it runs, in the step's working directory fails the step, naming the files."""
    import scenarios_run
    before = set(tmp_path.iterdir())
    (tmp_path / "run").mkdir()
    assert scenarios_run.stray_outputs("run", {"ok": True}, tmp_path, before) == {"ok": True}
    (tmp_path / "ssm_pas0.xml").write_text("<SSMLog/>")
    res = scenarios_run.stray_outputs("run", {"ok": True}, tmp_path, before)
    assert res["ok"] is False and "ssm_pas0.xml" in res["error"]
    assert scenarios_run.stray_outputs("sumo", {"ok": True}, tmp_path, before) == {"ok": True}


def test_one_line_takes_sumos_error_else_the_traceback_tail(corpus):
    sumo = "Warning: x\nError: No option with the name 'osg-view' exists.\nQuitting (on error).\n"
    assert corpus._one_line(sumo) == "Error: No option with the name 'osg-view' exists."
    assert corpus._one_line("Traceback ...\n  File x\nKeyError: 'lane'\n") == "KeyError: 'lane'"


def test_placement_counts_agents_at_any_depth(corpus, tmp_path):
    doc = {"agents": [{"status": "placed"}, {"status": "refused"}, {"status": "dropped"}],
           "tiles": [{"agents": [{"status": "placed"}, {"status": "placed"}]}]}
    (tmp_path / "f.json").write_text(json.dumps(doc))
    got = corpus.placement(tmp_path / "f.json")
    assert (got["agents"], got["placed"], got["refused"], got["placed_share"]) == (5, 3, 1, 0.75)
    assert corpus._share(got) == "75.0 % of 4 (1 dropped)"
    assert corpus.placement(tmp_path / "missing.json") is None


@pytest.mark.parametrize("copies", [1, 2])
def test_a_replay_holding_other_vehicles_than_the_folder_says_fails(corpus, tmp_path, copies):
    """A portable start that doubled every vehicle (as a --scale 2 did) exits 0 in stock SUMO; the
    step compares SUMO's vehicles at its first step (summary-output) with fill.json's placed ones."""
    from sumo_scendiff.core.tools import sumo_binary
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "200",
                    "-o", str(tmp_path / "g.net.xml")], check=True, capture_output=True)
    edges = ["A0A1", "A1A2", "B0B1", "B1B2", "C0C1", "C1C2", "A1B1", "B1C1"]
    vehicles = [f'<vehicle id="v{k}_{c}" depart="10" departPos="{20 + 60 * c}" departLane="best">'
                f'<route edges="{e}"/></vehicle>' for c in range(copies) for k, e in enumerate(edges)]
    (tmp_path / "start.rou.xml").write_text("<routes>" + "".join(vehicles) + "</routes>")
    (tmp_path / "fill").mkdir()
    (tmp_path / "fill" / "fill.json").write_text(json.dumps({"agents": [{"status": "placed"}] * len(edges)}))
    cmd = [corpus._sumo(), "-n", tmp_path / "g.net.xml", "-r", tmp_path / "start.rou.xml", "-b", "10", "-e", "20",
           "--no-step-log", "true", "--summary-output", tmp_path / "fill_start_summary.xml"]
    res = corpus.check_count("fill_start", corpus.step(cmd, 60, tmp_path / "log", tmp_path), tmp_path)
    assert res["vehicles"] == {"sumo": len(edges) * copies, "expected": len(edges)}
    if copies == 1:
        assert res["ok"]
    else:
        assert res["ok"] is False and res["error"] == "start holds 16 vehicles, fill.json placed 8"
    assert corpus.first_failure({"steps": {"fill_start": res}})[0] == (None if copies == 1 else "fill_start")


@pytest.mark.parametrize("numbered_on", [False, True])
def test_a_replay_counts_the_demands_departures_due_in_its_first_step(corpus, tmp_path, numbered_on):
    """As sumo-experiments' Bologna: three of the demand's own vehicles depart in the portable start's
    first step beside its eight seeded ones; they are the demand's, measured by SUMO in the start's
    configuration without its own file, not a fault of the start. The demand's flows the fill writes
    numbered on (flows.rou.xml: game_cross) are the demand's too: all but the start's own file."""
    from sumo_scendiff.core.tools import sumo_binary
    fill = tmp_path / "fill"
    fill.mkdir()
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "200",
                    "-o", str(fill / "g.net.xml")], check=True, capture_output=True)
    edges = ["A0A1", "A1A2", "B0B1", "B1B2", "C0C1", "C1C2", "A1B1", "B1C1"]
    (fill / "start.rou.xml").write_text("<routes>" + "".join(
        f'<vehicle id="s{k}" depart="10" departPos="80"><route edges="{e}"/></vehicle>'
        for k, e in enumerate(edges)) + "</routes>")
    (fill / "d.rou.xml").write_text("<routes>" + "".join(
        f'<vehicle id="d{k}" depart="10" departPos="10"><route edges="{e}"/></vehicle>'
        for k, e in enumerate(["A2A1", "B2B1", "C2C1"])) + "</routes>")
    routes, doc = "start.rou.xml,d.rou.xml", {"agents": [{"status": "placed"}] * len(edges),
                                              "routes": [str(tmp_path / "user" / "d.rou.xml")]}
    if numbered_on:
        (fill / "flows.rou.xml").write_text('<routes><vehicle id="f.7" depart="10" departPos="10">'
                                            '<route edges="C1B1"/></vehicle></routes>')
        routes, doc["portable_ids"] = routes + ",flows.rou.xml", "start.<vehicle> in start.rou.xml"
    (fill / "start.sumocfg").write_text('<configuration><net-file value="g.net.xml"/><begin value="10"/>'
                                        f'<route-files value="{routes}"/></configuration>')
    (fill / "fill.json").write_text(json.dumps(doc))
    cmd = [corpus._sumo(), "-c", fill / "start.sumocfg", "--end", "20", "--no-step-log", "true",
           "--summary-output", tmp_path / "fill_start_summary.xml"]
    res = corpus.check_count("fill_start", corpus.step(cmd, 60, tmp_path / "log", tmp_path), tmp_path)
    want = 11 + numbered_on
    assert res["ok"] and res["vehicles"] == {"sumo": want, "expected": want}, res
    assert not list(fill.glob("_*.sumocfg"))


def test_the_portable_starts_count_is_the_states(corpus, tmp_path):
    """The estimate's folder (fill.json names no ``portable_ids``): a flow the fill numbers on departs in
    the portable start's first step from its own file (flow_departures.rou.xml), which is the demand's
    as much as the user's route file is. Both replays are counted by one step of their own
    configuration: what it holds beyond the folder's own vehicles (start.rou.xml's, the state's)."""
    fill = _grid_fill(tmp_path)
    edges = ["A0A1", "A1A2", "B0B1", "B1B2"]
    (fill / "start.rou.xml").write_text("<routes>" + "".join(
        f'<vehicle id="fill{k}.0" depart="10" departPos="80"><route edges="{e}"/></vehicle>'
        for k, e in enumerate(edges)) + "</routes>")
    (fill / "d.rou.xml").write_text('<routes><vehicle id="d0" depart="10" departPos="10"><route edges="C2C1"/>'
                                    '</vehicle></routes>')
    (fill / "flow_departures.rou.xml").write_text('<routes><vehicle id="f.3" depart="10" departPos="10">'
                                                  '<route edges="C1B1"/></vehicle></routes>')
    (fill / "start.sumocfg").write_text('<configuration><net-file value="g.net.xml"/><begin value="10"/>'
                                        '<route-files value="start.rou.xml,d.rou.xml,flow_departures.rou.xml"/>'
                                        '</configuration>')
    (fill / "fill.json").write_text(json.dumps({"agents": [{"status": "placed"}] * len(edges),
                                                "routes": [str(tmp_path / "user" / "d.rou.xml")]}))
    cmd = [corpus._sumo(), "-c", fill / "start.sumocfg", "--end", "20", "--no-step-log", "true",
           "--summary-output", tmp_path / "fill_start_summary.xml"]
    res = corpus.check_count("fill_start", corpus.step(cmd, 60, tmp_path / "log", tmp_path), tmp_path)
    assert res["vehicles"] == {"sumo": 6, "expected": 6}, res


def test_a_state_replay_counts_the_departures_its_queue_holds_once(corpus, tmp_path):
    """As sumo-rl's Nguyen: the state saved at T holds SUMO's queue of vehicles due by T and not yet in;
    a route file's departures due in the replay's first step are among them (they were counted twice), a
    flow's are not (ma2c_real_net: they are due then)."""
    from sumo_scendiff.sim.state import waiting_in_state
    fill = _grid_fill(tmp_path)
    # six vehicles due at one spot at T = 10: one enters a second, the rest wait in SUMO's queue
    (fill / "d.rou.xml").write_text("<routes>" + "".join(
        f'<vehicle id="d{k}" depart="{5 if k < 2 else 10}"><route edges="A0A1 A1A2"/></vehicle>'
        for k in range(8)) + '<flow id="f" begin="10" end="11" number="1" from="C0C1" to="C1C2"/></routes>')
    subprocess.run([corpus._sumo(), "-n", fill / "g.net.xml", "-r", fill / "d.rou.xml", "--end", "12",
                    "--save-state.times", "10", "--save-state.files", fill / "state.xml.gz", "--no-step-log", "true"],
                   check=True, capture_output=True)
    on_road = ["d0", "d1"]
    queued = waiting_in_state(str(fill / "state.xml.gz"), on_road, 10.0)
    res = _state_replay(corpus, tmp_path, 10.0, len(on_road), queued)
    # the flow's vehicle due at T is made then, not held in the state: due in the replay's first step
    assert queued == 6 and res["ok"] and res["vehicles"] == {"sumo": 9, "expected": 9}, res


def test_a_state_replay_counts_the_vehicles_arriving_in_its_first_step(corpus, tmp_path):
    """As feat_distributions: the state saved at T holds cars at their arrival, which SUMO takes off the
    road in the replay's first step (its summary's first step is counted after it), beside a queue of
    vehicles due and not yet in, each of which enters then or waits on: SUMO holds the state's cars
    less those arriving plus the whole queue, not a fault of the state."""
    import xml.etree.ElementTree as ET

    from sumo_scendiff.sim.state import waiting_in_state
    fill = _grid_fill(tmp_path)
    # four cars alike (no chance in their driving) arriving together, and five due at one spot
    (fill / "d.rou.xml").write_text('<routes><vType id="t" sigma="0" speedDev="0"/>' + "".join(
        f'<vehicle id="a{k}" type="t" depart="0" departPos="0" arrivalPos="150"><route edges="{e}"/></vehicle>'
        for k, e in enumerate(["A0A1", "B0B1", "C0C1", "A1A2"])) + "".join(
        f'<vehicle id="q{k}" depart="5"><route edges="B1B2"/></vehicle>' for k in range(5)) + "</routes>")
    trips = tmp_path / "trips.xml"
    subprocess.run([corpus._sumo(), "-n", fill / "g.net.xml", "-r", fill / "d.rou.xml", "--end", "60",
                    "--tripinfo-output", trips, "--no-step-log", "true"], check=True, capture_output=True)
    span = {v.get("id"): (float(v.get("depart")), float(v.get("arrival")))
            for v in ET.parse(trips).getroot().iter("tripinfo")}
    t = span["a0"][1]
    assert all(span[f"a{k}"][1] == t for k in range(4))
    subprocess.run([corpus._sumo(), "-n", fill / "g.net.xml", "-r", fill / "d.rou.xml", "--end", f"{t + 1:g}",
                    "--save-state.times", f"{t:g}", "--save-state.files", fill / "state.xml.gz",
                    "--no-step-log", "true"], check=True, capture_output=True)
    on_road = [v for v, (depart, arrival) in span.items() if depart < t <= arrival]    # the state's at t
    queued = waiting_in_state(str(fill / "state.xml.gz"), on_road, t)
    res = _state_replay(corpus, tmp_path, t, len(on_road), queued)
    assert queued >= 1 and len(on_road) >= 5
    want = len(on_road) + queued - 4
    assert res["ok"] and res["vehicles"] == {"sumo": want, "expected": want}, res


def _grid_fill(tmp_path: Path) -> Path:
    """A fill folder ``tmp_path/fill`` holding netgenerate's 3x3 grid of 200 m blocks, g.net.xml."""
    from sumo_scendiff.core.tools import sumo_binary
    fill = tmp_path / "fill"
    fill.mkdir()
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "200",
                    "-o", str(fill / "g.net.xml")], check=True, capture_output=True)
    return fill


def _state_replay(corpus, tmp_path: Path, t: float, placed: int, queued: int) -> dict:
    """The fill_replay step's count of the state ``tmp_path/fill/state.xml.gz`` saved at ``t`` from the
    demand ``d.rou.xml``, fill.json saying ``placed`` agents and ``queued`` waiting to enter."""
    fill = tmp_path / "fill"
    (fill / "scenario.sumocfg").write_text(f'<configuration><net-file value="g.net.xml"/><begin value="{t:g}"/>'
                                           '<route-files value="d.rou.xml"/><load-state value="state.xml.gz"/>'
                                           '</configuration>')
    (fill / "fill.json").write_text(json.dumps({"agents": [{"status": "placed"}] * placed,
                                                "routes": [str(tmp_path / "user" / "d.rou.xml")],
                                                "density": {"waiting_to_enter": queued}, "state_time": t}))
    cmd = [corpus._sumo(), "-c", fill / "scenario.sumocfg", "--end", f"{t + 10:g}", "--no-step-log", "true",
           "--summary-output", tmp_path / "fill_replay_summary.xml"]
    return corpus.check_count("fill_replay", corpus.step(cmd, 60, tmp_path / "log", tmp_path), tmp_path)


def test_the_run_replays_reference_takes_no_traci_client(corpus, tmp_path, monkeypatch):
    """As sumo-rl's OW: a configuration with remote-port; stock SUMO's reference run for the scene's count
    waited for a TraCI client until its time limit (no count), its binary left holding the port."""
    from sumo_scendiff.core.tools import sumo_binary
    import scenarios_counts
    monkeypatch.setattr(scenarios_counts, "REFERENCE_TIMEOUT", 20)
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "200",
                    "-o", str(tmp_path / "g.net.xml")], check=True, capture_output=True)
    (tmp_path / "d.rou.xml").write_text('<routes><flow id="f" begin="0" end="60" period="5" from="A0A1" '
                                        'to="A1A2"/></routes>')
    (tmp_path / "s.sumocfg").write_text('<configuration><net-file value="g.net.xml"/><route-files value="d.rou.xml"/>'
                                        '<remote-port value="47311"/></configuration>')
    out = tmp_path / "out"
    (out / "run" / "scene_000").mkdir(parents=True)
    (out / "run" / "run.json").write_text(json.dumps({"configuration": str(tmp_path / "s.sumocfg")}))
    (out / "run" / "scene_000" / "scene.json").write_text(json.dumps({"time": 30.0, "sumo_options": {"seed": 0},
                                                                       "agents": []}))
    count, words = scenarios_counts.expected_vehicles("run_replay", out)
    assert count is not None and count > 0 and "stock SUMO" in words, words


def test_table_names_the_first_failing_step(corpus):
    row = {"name": "n", "source": "s", "licence": "MIT", "covers": ["buses"],
           "steps": {"sumo": {"ok": True, "seconds": 1.0},
                     "run": {"ok": False, "seconds": 2.0, "error": "a | b", "cmd": "python -m x"},
                     "run_replay": {"ok": None, "error": "skip: run failed"}}}
    table = corpus.markdown([row])
    assert "| n | s | MIT | buses | ok | FAIL | skip |" in table
    assert "run: a \\| b" in table
