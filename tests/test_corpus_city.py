"""The corpus's city-scale builds (benchmarks/scenarios_city.py): MoST's road network numbered as its authors'
merger numbered it, routes the rebuilt network cannot drive repaired, and the harness's stock step reading its
summary where a configuration names an output-prefix."""
from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from tests.corpus_support import HERE, load_corpus

sys.path.insert(0, str(HERE.parent / "benchmarks"))
import scenarios_city  # noqa: E402


@pytest.fixture(scope="module")
def corpus():
    return load_corpus()


OSM = """<?xml version='1.0' encoding='UTF-8'?>
<osm version="0.6">
  <node id="-1" lat="43.7300000" lon="7.4200000"><tag k="ele" v="10.0"/></node>
  <node id="-2" lat="43.7310000" lon="7.4200000"><tag k="ele" v="10.0"/></node>
  <node id="-3" lat="43.7310000" lon="7.4200000"><tag k="ele" v="10.0"/></node>
  <node id="-4" lat="43.7320000" lon="7.4210000"/>
  <way id="-90"><nd ref="-1"/><nd ref="-2"/><tag k="highway" v="secondary"/></way>
  <way id="-80"><nd ref="-3"/><nd ref="-4"/><tag k="highway" v="secondary"/></way>
  <relation id="-7"><member type="way" ref="-80" role="from"/><member type="node" ref="-3" role="via"/></relation>
</osm>
"""


def test_most_ways_are_numbered_as_the_merger_numbered_them(tmp_path):
    src, out = tmp_path / "network.osm", tmp_path / "raw.osm"
    src.write_text(OSM)
    scenarios_city.most_raw_osm(src, out, first_way=500)
    root = ET.parse(out).getroot()
    assert [w.get("id") for w in root.iter("way")] == ["500", "501"]
    # nodes at one place and elevation are one node: the two ways meet there
    assert [n.get("id") for n in root.iter("node")] == ["-1", "-2", "-4"]
    assert [nd.get("ref") for nd in root.iter("nd")] == ["-1", "-2", "-2", "-4"]
    assert [(m.get("type"), m.get("ref")) for m in root.iter("member")] == [("way", "501"), ("node", "-2")]
    net = tmp_path / "net.net.xml"
    subprocess.run(["netconvert", "--osm-files", str(out), "-o", str(net)], check=True, capture_output=True)
    edges = {e.get("id") for e in ET.parse(net).getroot().iter("edge") if e.get("function") != "internal"}
    assert {"500", "501"} <= edges


@pytest.fixture
def grid(tmp_path):
    net = tmp_path / "grid.net.xml"
    subprocess.run(["netgenerate", "--grid", "--grid.number", "3", "--grid.length", "100", "-o", str(net)],
                   check=True, capture_output=True)
    import sumolib
    return sumolib.net.readNet(str(net))


def test_a_route_through_an_unknown_edge_is_repaired_and_the_rest_kept(tmp_path, grid):
    routes = tmp_path / "r.rou.xml"
    good = '<route id="good" edges="A0A1 A1A2"/>'
    text = (f'<routes>\n    {good}\n    <vehicle id="v" depart="0">'
            '<route edges="A0A1 A1B1#2 B1C1"/></vehicle>\n</routes>\n')
    routes.write_text(text)
    assert scenarios_city.repair_routes(routes, grid) == 1
    new = routes.read_text()
    assert good in new
    edges = ET.fromstring(new).find("vehicle/route").get("edges").split()
    assert edges[0] == "A0A1" and edges[-1] == "B1C1" and "A1B1#2" not in edges
    assert all(grid.getEdge(a).getConnections(grid.getEdge(b)) for a, b in zip(edges, edges[1:]))


def test_a_configurations_files_the_snapshot_lacks_are_left_out(tmp_path):
    cfg = tmp_path / "c.sumocfg"
    cfg.write_text('<configuration><input><net-file value="n.net.xml"/>'
                   '<route-files value="a.rou.xml,gone.rou.xml,b.rou.xml"/>'
                   '<additional-files value="gone.add.xml,c.add.xml"/></input></configuration>')
    scenarios_city._without_absent(cfg, ["gone.rou.xml", "gone.add.xml"])
    root = ET.parse(cfg).getroot()
    assert root.find("input/route-files").get("value") == "a.rou.xml,b.rou.xml"
    assert root.find("input/additional-files").get("value") == "c.add.xml"


def test_the_stock_step_reads_its_summary_under_an_output_prefix(corpus, tmp_path):
    net = tmp_path / "net.net.xml"
    subprocess.run(["netgenerate", "--grid", "--grid.number", "2", "-o", str(net)], check=True,
                   capture_output=True)
    cfg = tmp_path / "s.sumocfg"
    cfg.write_text('<configuration><input><net-file value="net.net.xml"/></input>'
                   '<output><output-prefix value="most."/></output></configuration>')
    out = tmp_path / "out"
    (out / "logs").mkdir(parents=True)
    cmd = corpus.commands(cfg, 10.0, (0, 0, 100, 100), out)["sumo"]
    assert corpus.step(cmd, 60, out / "logs" / "sumo.log", out)["ok"]
    assert (out / "sumo_summary.xml").is_file()


def _reference_folder(tmp_path, cfg_extra: str):
    """A run's folder whose scene (at 30 s) the run replay's reference counts, on a configuration of a tiny
    grid and a flow with ``cfg_extra`` in it."""
    subprocess.run(["netgenerate", "--grid", "--grid.number", "3", "--grid.length", "200",
                    "-o", str(tmp_path / "g.net.xml")], check=True, capture_output=True)
    (tmp_path / "d.rou.xml").write_text('<routes><flow id="f" begin="0" end="60" period="5" from="A0A1" '
                                        'to="A1A2"/></routes>')
    (tmp_path / "s.sumocfg").write_text('<configuration><net-file value="g.net.xml"/><route-files value="d.rou.xml"/>'
                                        f'{cfg_extra}</configuration>')
    out = tmp_path / "out"
    (out / "run" / "scene_000").mkdir(parents=True)
    (out / "run" / "run.json").write_text(json.dumps({"configuration": str(tmp_path / "s.sumocfg")}))
    (out / "run" / "scene_000" / "scene.json").write_text(json.dumps({"time": 30.0, "sumo_options": {"seed": 0},
                                                                       "agents": []}))
    return out


def test_the_run_replays_reference_counts_under_an_output_prefix(corpus, tmp_path):
    import scenarios_counts
    out = _reference_folder(tmp_path, '<output-prefix value="most."/>')
    count, words = scenarios_counts.expected_vehicles("run_replay", out)
    assert count > 0 and "stock SUMO" in words, words


def test_a_replay_that_cannot_be_counted_fails_in_one_line(corpus, tmp_path, monkeypatch):
    """The reference over its time limit (F21) and a replay without a summary: the step fails, no traceback."""
    import scenarios_counts
    monkeypatch.setattr(scenarios_counts, "REFERENCE_TIMEOUT", 0.01)
    out = _reference_folder(tmp_path, "")
    res = scenarios_counts.check_count("run_replay", {"ok": True}, out)
    assert res["ok"] is False and "took over" in res["error"], res
    (out / "run" / "scene_000" / "scene.json").unlink()
    res = scenarios_counts.check_count("run_replay", {"ok": True}, out)
    assert res["ok"] is False and "could not count" in res["error"], res
