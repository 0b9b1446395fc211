"""A sweep over a user's own SUMO scenario (a network entry with ``config``), read as ``run -c`` reads
it: its vTypes (the fleet), step length, options, additional files, demand in additional files."""
from __future__ import annotations

import json
import os
import shutil
import xml.etree.ElementTree as ET

import pytest

from sumo_scendiff.sweep.spec import SpecError, load_spec

from .test_sweep import _main

TYPES = """<additional>
    <vType id="car" vClass="passenger" length="4.3" width="1.7" minGap="1.5" accel="2.2" decel="4.0"/>
    <vType id="coach" vClass="bus" length="12.0" width="2.55" minGap="2.0" accel="1.0" decel="3.5"/>
</additional>
"""
FLOWS = ('<flow id="cars" type="car" begin="0" end="300" period="4" from="wc" to="ce"/>'
         '<flow id="coaches" type="coach" begin="0" end="300" period="6" from="sc" to="cn"/>')
SIZES = {"car": (4.3, 1.7), "coach": (12.0, 2.55)}
# the scenario's own step (SUMO's default with a demand is 1 s) and an option on how SUMO runs it
CONFIG = """<configuration>
  <input><net-file value="cross.net.xml"/>{routes}<additional-files value="{additional}"/></input>
  <time><begin value="0"/><step-length value="0.25"/></time>
  <processing><time-to-teleport value="123"/></processing>
</configuration>
"""


@pytest.fixture(scope="module")
def scenario(cross_net, tmp_path_factory):
    """A user's folder with two configurations: one with a route file, one whose demand lives in an
    additional file beside the vTypes (as SUMO's games ship theirs)."""
    d = tmp_path_factory.mktemp("user") / "scen"
    d.mkdir()
    shutil.copy(cross_net, d / "cross.net.xml")
    (d / "types.add.xml").write_text(TYPES)
    (d / "demand.rou.xml").write_text(f"<routes>{FLOWS}</routes>")
    (d / "traffic.add.xml").write_text(f"<additional>{FLOWS}</additional>")
    (d / "routed.sumocfg").write_text(CONFIG.format(routes='<route-files value="demand.rou.xml"/>',
                                                     additional="types.add.xml"))
    (d / "games.sumocfg").write_text(CONFIG.format(routes="", additional="types.add.xml,traffic.add.xml"))
    return d


def _spec(scenario, networks: str, rest: str = "") -> str:
    """A spec in a folder beside the scenario's, its paths relative to it."""
    path = scenario.parent / "spec" / "s.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(f"networks = [{networks}]\nlocations = [{{center = [0.0, 0.0]}}]\np_mask = [1.0]\n"
                    f"vehicles = [12]\nseeds = 1\nsteps = 4\nrollout = 1.0\n{rest}")
    return str(path)


def test_an_entry_is_read_as_run_reads_c_n_r_a(scenario):
    """The configuration's inputs, step and options; routes and additional (a path or a list)
    replace what it names, as -r/-a with -c; the spec's step_length is over the scenario's."""
    path = _spec(scenario, '{config = "../scen/routed.sumocfg"}, '
                           '{config = "../scen/games.sumocfg", routes = ["../scen/demand.rou.xml"], '
                           'additional = "../scen/types.add.xml"}')
    spec = load_spec(path)
    assert list(spec.networks) == ["routed", "games"]
    routed, games = (spec.scenario_of(n) for n in spec.networks)
    assert routed.net == str(scenario / "cross.net.xml") and routed.additional == (str(scenario / "types.add.xml"),)
    assert ("time-to-teleport", "123") in routed.options
    assert games.routes == (str(scenario / "demand.rou.xml"),) and games.additional == routed.additional
    assert [s.step_length for s in spec.scenarios()] == [0.25, 0.25]
    over = load_spec(_spec(scenario, '{config = "../scen/routed.sumocfg"}', "step_length = 0.5\n"))
    assert [s.step_length for s in over.scenarios()] == [0.5]


@pytest.mark.parametrize("entry, message", [
    ('{config = "../scen/nothere.sumocfg"}', "networks[0].config: {d}/nothere.sumocfg: no such file"),
    ('{config = "../scen/routed.sumocfg", additional = ["../scen/gone.add.xml"]}',
     "networks[0].additional: {d}/gone.add.xml: no such file"),
    ('{config = "../scen/routed.sumocfg", routes = "../scen/gone.rou.xml"}',
     "networks[0].routes: {d}/gone.rou.xml: no such file"),
    ('{config = "../scen/routed.sumocfg", vtypes = "x"}', "networks[0].vtypes: unknown key"),
    ('{net = "../scen/routed.sumocfg"}', "networks[0].net: ../scen/routed.sumocfg: a SUMO configuration"),
    ('{config = "../scen/cross.net.xml"}',
     "networks[0].config: ../scen/cross.net.xml: a SUMO network, not a configuration"),
    ('{config = "../scen/routed.sumocfg", additional = []}', "networks[0].additional: must be a path"),
    ('{routes = "../scen/demand.rou.xml"}', "networks[0]: needs 'net' or 'config'"),
])
def test_a_bad_entry_is_one_line_before_any_work(scenario, entry, message, capsys):
    path = _spec(scenario, entry)
    message = message.format(d=scenario)
    out = scenario.parent / "out"
    code, _, err = _main(["--spec", path, "--out", str(out)], capsys)
    assert code == 2 and err.count("\n") == 1 and path in err and message in err, err
    assert not out.exists()
    with pytest.raises(SpecError):
        spec = load_spec(path)
        for name in spec.networks:
            spec.scenario_of(name)


def _seeded(folder) -> list[dict]:
    with open(os.path.join(folder, "scene.json")) as f:
        return [a for a in json.load(f)["agents"] if a["vehicle"]]


def _options(folder) -> dict[str, str]:
    return {el.tag: el.get("value") for el in ET.parse(os.path.join(folder, "scenario.sumocfg")).getroot()}


@pytest.mark.slow
def test_a_sweep_over_a_users_scenario_keeps_it(scenario, tmp_path, capsys):
    """Both configurations run: the seeded vehicles are the scenario's vTypes, the demand (a route
    file, or an additional file) was warmed to begin and is in the window, and each exported
    scenario.sumocfg keeps the step length, the option and the additional files."""
    path = _spec(scenario, '{config = "../scen/routed.sumocfg", begin = 40}, '
                           '{config = "../scen/games.sumocfg", begin = 40}')
    out = tmp_path / "out"
    code, stdout, err = _main(["--spec", path, "--out", str(out), "--no-pictures"], capsys)
    assert code == 0, stdout + err
    with open(out / "index.jsonl") as f:
        rows = [json.loads(line) for line in f]
    assert [(r["network"], r["status"], r["step_length"]) for r in rows] == [("routed", "ok", 0.25),
                                                                            ("games", "ok", 0.25)]
    for r in rows:
        folder = out / r["id"]
        assert r["existing_vehicles"] > 0, r          # the demand ran to t = 40 s before seeding
        seeded = _seeded(folder)
        assert seeded and all(a["vtype"] in SIZES for a in seeded)
        assert all((a["length"], a["width"]) == pytest.approx(SIZES[a["vtype"]]) for a in seeded)
        opts = _options(folder)
        assert opts["step-length"] == "0.25" and opts["time-to-teleport"] == "123"
        added = opts["additional-files"].split(",")
        assert any(os.path.basename(a).startswith("types.add.xml") for a in added)   # (bundled: .gz)
        assert all(os.path.isfile(os.path.join(folder, a)) for a in added)   # they travel in the folder


def test_a_route_file_cut_short_is_warned_and_a_begin_after_it_refused(scenario, capsys):
    """As run: SUMO reads such a file up to its cut and quits there; the sweep says so once, before
    any work, and a begin after it is one line, exit 2."""
    cut = scenario / "cut.rou.xml"
    whole = "".join(f'<vehicle id="v{t}" depart="{t}"><route edges="wc ce"/></vehicle>\n' for t in range(0, 1001, 20))
    cut.write_text("<routes>\n" + whole + '<vehicle id="v1020" depart="1020"><route edg')
    from sumo_scendiff.sweep.__main__ import check_demand_times
    spec = load_spec(_spec(scenario, '{config = "../scen/routed.sumocfg", routes = "../scen/cut.rou.xml", begin = 60}'))
    name = next(iter(spec.networks))
    check_demand_times("s.toml", name, spec.networks[name], spec.scenario_of(name))
    err = capsys.readouterr().err
    assert err.count("warning") == 1 and "cut.rou.xml" in err
    late = _spec(scenario, '{config = "../scen/routed.sumocfg", routes = "../scen/cut.rou.xml", begin = 990}')
    out = scenario.parent / "late"
    code, _, err = _main(["--spec", late, "--out", str(out)], capsys)
    assert code == 2 and "cut.rou.xml" in err and "Traceback" not in err and not out.exists(), err


def test_a_config_naming_a_missing_file_says_how_the_spec_replaces_it(scenario, capsys):
    (scenario / "lost.sumocfg").write_text(CONFIG.format(routes='<route-files value="gone.rou.xml"/>',
                                                         additional="types.add.xml"))
    path = _spec(scenario, '{config = "../scen/lost.sumocfg"}')
    code, _, err = _main(["--spec", path, "--out", str(scenario.parent / "lost-out")], capsys)
    assert code == 2 and "gone.rou.xml: no such file" in err and "the entry's net/routes/additional" in err
    assert "-n/-r/-a" not in err and err.count("\n") == 1, err
