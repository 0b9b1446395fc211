"""fill with the demand kept in an additional file (SUMO's games keep theirs so): SUMO's own run to
--begin or the estimate, as with a route file; the exported folder replays in stock SUMO with each
vehicle once, the additional file's other contents kept (real SUMO)."""
from __future__ import annotations

import gzip
import os
import subprocess
import xml.etree.ElementTree as ET

import pytest

from .test_fill_warm_start import _sumos_own
from .test_warmup import DEMAND

# the demand of tests/test_warmup.py as an additional file, with what else such a file holds: a bus
# stop, a detector writing into a results folder, a person walking
TRAFFIC = DEMAND.replace("<routes>", "<additional>").replace("</routes>", "</additional>").replace(
    '  <vehicle id="late"', '  <busStop id="stop" lane="ce_0" startPos="60" endPos="80"/>\n'
    '  <inductionLoop id="loop" lane="wc_0" pos="100" period="60" file="results/loop.xml"/>\n'
    '  <person id="walker" depart="50"><walk edges="wc ce"/></person>\n  <vehicle id="late"')


@pytest.fixture()
def game(cross_net, tmp_path, monkeypatch):
    """(network, the additional file with the demand, a .sumocfg loading it)."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))     # the saved states go here
    user = tmp_path / "user"
    (user / "results").mkdir(parents=True)
    add = user / "traffic.add.xml"
    add.write_text(TRAFFIC)
    cfg = user / "game.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{cross_net}"/><additional-files value="traffic.add.xml"/>'
                   '</input><time><step-length value="1"/></time></configuration>')
    return cross_net, str(add), str(cfg)


def _replay(folder: str, cfg: str, tmp_path) -> int:
    """Stock sumo on the folder's ``cfg`` for a few steps: the vehicles running at its first step
    (it must load: a vehicle twice is an error SUMO quits on)."""
    from sumo_scendiff.core.tools import sumo_binary
    summary = tmp_path / f"{os.path.basename(folder)}-{cfg}.summary.xml"
    done = subprocess.run([sumo_binary(), "-c", os.path.join(folder, cfg), "--end", "125", "--no-step-log", "true",
                           "--summary-output", str(summary)], capture_output=True, text=True)
    assert done.returncode == 0 and "rror" not in done.stderr, done.stderr[-400:]
    return int(next(ET.parse(summary).getroot().iter("step")).get("running"))


def _close(replayed: int, seeded: int) -> bool:
    return abs(replayed - seeded) <= max(2, 0.02 * seeded)


def _carried(folder: str) -> str:
    """The folder's copy of the additional file."""
    with gzip.open(os.path.join(folder, "traffic.add.xml.gz"), "rt") as f:
        return f.read()


def test_sumos_own_run_of_an_additional_files_demand(game, tmp_path):
    """-c with the demand in its additional files: SUMO's own run to --begin, as a route file's
    (before, the fill took the scenario for one without demand and drew the model's prior)."""
    from sumo_scendiff.fill.api import fill
    net, add, cfg = game
    done = fill(config=cfg, begin=120.0, out=str(tmp_path / "filled"))
    assert done.doc["density"]["kind"] == "demand" and done.doc["density"]["start"] == "sumo"
    own = _sumos_own(net, None, 120.0, additional=(add,))
    assert {a["vehicle"] for a in done.doc["agents"]} == own and len(own) > 5
    assert done.summary["vehicles"] == len(own) and done.summary["refused"] == 0
    assert done.doc["inflow"]["file"] is None       # the demand continues: no inflow of our own
    for name in ("scenario.sumocfg", "start.sumocfg"):
        assert _close(_replay(done.folder, name, tmp_path), len(own)), name
    carried = _carried(done.folder)
    assert all(f'<{tag} id="{i}"' in carried for tag, i in (("busStop", "stop"), ("inductionLoop", "loop"),
                                                            ("person", "walker")))
    # the flow that departed before T: its departures on, named as SUMO's own run names them (fill/flow_ids.py)
    with open(os.path.join(done.folder, "flow_departures.rou.xml")) as f:
        assert '<flow id="f_we"' not in carried and '<vehicle id="f_we.' in f.read()


def test_an_additional_file_on_the_command_line(game, tmp_path):
    """-n with -a holding the demand: the same start as the configuration's."""
    from sumo_scendiff.fill.__main__ import get_options, main
    net, add, _ = game
    out = tmp_path / "cli"
    assert main(get_options(["-n", net, "-a", add, "--begin", "120", "--step-length", "1", "-o", str(out), "-q"])) == 0
    import json
    with open(out / "fill.json") as f:
        doc = json.load(f)
    own = _sumos_own(net, None, 120.0, additional=(add,))
    assert doc["density"]["start"] == "sumo" and {a["vehicle"] for a in doc["agents"]} == own
    assert _close(_replay(str(out), "start.sumocfg", tmp_path), len(own))


@pytest.mark.slow     # the model fills the tiles
def test_the_estimate_reads_an_additional_files_demand(cross_net, tmp_path):
    """--demand-estimate: the additional file's departures before the state's time are the fill's,
    the fill's SUMO loads the file without them (else it would insert one departing at --begin a
    second time), the later ones depart from the carried file; each once."""
    from sumo_scendiff.fill.api import fill

    from .test_fill_demand import replayed
    times = [("early", 60), ("at", 120), ("within", 120.25), ("due", 120.5), ("later", 125)]
    add = tmp_path / "traffic.add.xml"
    add.write_text('<additional><busStop id="stop" lane="ce_0" startPos="60" endPos="80"/>' + "".join(
        f'<vehicle id="{v}" depart="{t}"><route edges="{e}"/></vehicle>'
        for (v, t), e in zip(times, ["wc ce", "sc cn", "ec cw", "nc cs", "wc cn"])) + "</additional>")
    done = fill(cross_net, additional=(str(add),), begin=120.0, step_length=0.5, demand_estimate=True,
                out=str(tmp_path / "o"))
    assert done.doc["density"]["kind"] == "demand" and done.doc["density"]["departed"] == 3
    carried = {a["demand"]["id"] for a in done.doc["agents"] if a.get("demand") and a["vehicle"]}
    assert {"at", "within"} <= carried and not carried & {"due", "later"}
    assert '<busStop id="stop"' in _carried(done.folder)
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        _, present, departed = replayed(os.path.join(done.folder, cfg), 130.0)
        assert present.isdisjoint(dict(times)), cfg      # the state: the fill's vehicles alone
        assert sorted(v for v in departed if v in dict(times)) == ["due", "later"], cfg
    assert _close(_replay(done.folder, "start.sumocfg", tmp_path), done.summary["vehicles"])


def test_an_additional_file_without_its_demand(tmp_path):
    """The fill's own SUMO loads a demand's additional file without its vehicles: the rest kept (a
    calibrator's flow is no demand), an included file's vehicles gone too, relative inputs found."""
    from sumo_scendiff.data.demand import demand_files, write_without_demand
    user = tmp_path / "user"
    user.mkdir()
    (user / "more.add.xml").write_text('<additional><vType id="slow" maxSpeed="5"/>'
                                       '<trip id="t" depart="3" from="wc" to="ce"/></additional>')
    (user / "calibrated.add.xml").write_text('<additional><calibrator id="c" lane="wc_0" pos="10" output="c.xml">'
                                             '<flow begin="0" end="60" vehsPerHour="300"/></calibrator></additional>')
    add = user / "traffic.add.xml"
    add.write_text('<additional><include href="more.add.xml"/><route id="r" edges="wc ce"/>'
                   '<busStop id="s" lane="ce_0" startPos="5" endPos="20"/><flow id="f" route="r" begin="0" '
                   'end="60" number="3"/><person id="p" depart="1"><walk edges="wc ce"/></person>'
                   '<rerouter id="rr" edges="wc" file="rerouter.def.xml"/></additional>')
    assert demand_files([], [str(user / "calibrated.add.xml"), str(add)]) == [str(add)]
    out = tmp_path / "work"
    out.mkdir()
    copy = ET.parse(write_without_demand(str(add), str(out))).getroot()
    assert [el.tag for el in copy] == ["include", "route", "busStop", "rerouter"]
    assert copy.find("rerouter").get("file") == str(user / "rerouter.def.xml")
    included = ET.parse(copy.find("include").get("href")).getroot()
    assert [el.tag for el in included] == ["vType"]
    assert not demand_files([], [str(out / name) for name in os.listdir(out)])
