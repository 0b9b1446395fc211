"""A scenario's additional files with outputs: ours never write them beside the user's files, the
exported folder has the subfolders they write into (real SUMO)."""
from __future__ import annotations

import os
import subprocess

from sumo_scendiff.sim.additional import output_folders, quiet_outputs


def _scenario(tmp_path, cross_net, include=True):
    user = tmp_path / "user"
    (user / "results").mkdir(parents=True)
    (user / "results" / "e1.xml").write_text("the user's own results")
    (user / "more.add.xml").write_text('<additional><vType id="slow" maxSpeed="5"/></additional>')
    add = user / "det.add.xml"
    add.write_text('<additional>' + ('<include href="more.add.xml"/>' if include else '') +
                   '<inductionLoop id="e1" lane="wc_0" pos="100" period="5" file="results/e1.xml"/>'
                   '<edgeData id="ed" period="5" file="results/edges/ed.xml"/></additional>')
    return user, add


def test_our_runs_leave_the_users_outputs_alone(tmp_path, cross_net):
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    user, add = _scenario(tmp_path, cross_net)
    assert output_folders(str(add)) == ["results", os.path.join("results", "edges")]
    (copy,) = quiet_outputs([str(add)])
    assert copy != str(add) and 'file="NUL"' in open(copy).read()
    assert quiet_outputs([str(user / "more.add.xml")]) == (str(user / "more.add.xml"),)   # nothing to quiet
    sim = start(SimConfig(net=cross_net, additional=(str(add),)))
    try:
        assert "slow" in sim.vehicletype.getIDList()          # the include still found
        for _ in range(20):
            sim.simulationStep()
    finally:
        close(sim)
    assert (user / "results" / "e1.xml").read_text() == "the user's own results"
    assert not (user / "results" / "edges").exists()


def test_the_exported_folder_has_its_outputs_folders(tmp_path, cross_net):
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.sim.export import write_sumocfg
    _, add = _scenario(tmp_path, cross_net, include=False)
    folder = tmp_path / "out"
    folder.mkdir()
    write_sumocfg(str(folder / "scenario.sumocfg"), {"net-file": cross_net, "additional-files": str(add),
                                                      "end": "20"}, None)
    done = subprocess.run([sumo_binary("sumo"), "-c", str(folder / "scenario.sumocfg"), "--no-step-log"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (folder / "results" / "e1.xml").exists() and (folder / "results" / "edges" / "ed.xml").exists()


def test_an_additional_file_with_vehicles_is_part_of_the_demand(tmp_path):
    """SUMO loads vehicles and flows from an additional file as demand (SUMO's games keep theirs in
    one): run warms such a scenario to --begin as it does a route file's."""
    from sumo_scendiff.data.demand import demand_files
    vehicles = tmp_path / "traffic.add.xml"
    vehicles.write_text('<additional><vType id="car"/><flow id="f" type="car" from="a" to="b" '
                        'begin="0" end="60" number="5"/></additional>')
    detectors = tmp_path / "detectors.add.xml"
    detectors.write_text('<additional><inductionLoop id="d" lane="a_0" pos="5" period="60" '
                         'file="NUL"/></additional>')
    routes = str(tmp_path / "demand.rou.xml")
    assert demand_files([routes], [str(detectors), str(vehicles)]) == [routes, str(vehicles)]
    assert demand_files([], [str(detectors)]) == []
