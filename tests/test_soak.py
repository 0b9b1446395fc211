"""The soak's short version (benchmarks/soak.py): a co-simulation of 120 s on a small generated
network with a demand from SUMO's randomTrips, two egos re-seeded as they drive and replaced when they
arrive; what the project added and SUMO removed leaves nothing behind in the co-simulation object,
whose containers stay within the network's size. Behaviour only: no time is asserted."""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import pytest
import sumolib

HERE = os.path.dirname(os.path.abspath(__file__))
NET = os.path.join(HERE, "..", "networks", "grid4x4_2lane_tls.net.xml")

pytestmark = pytest.mark.slow


def _bench():
    spec = importlib.util.spec_from_file_location("bench_soak", os.path.join(HERE, "..", "benchmarks", "soak.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One soak: its result and the network's size (lanes and edges, internal ones included)."""
    import sumo
    d = tmp_path_factory.mktemp("soak")
    trips = d / "trips.rou.xml"
    subprocess.run([sys.executable, os.path.join(sumo.SUMO_HOME, "tools", "randomTrips.py"), "-n", NET,
                    "-o", str(trips), "-e", "150", "-p", "1.5", "--seed", "1"], check=True, capture_output=True,
                   cwd=d)    # randomTrips writes its checked routes.rou.xml into the working directory
    cfg = d / "soak.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{os.path.abspath(NET)}"/>'
                   f'<route-files value="{trips}"/></input><time><begin value="0"/><end value="150"/></time>'
                   "</configuration>")
    bench = _bench()
    o = bench.get_options(["-c", str(cfg), "--duration", "120", "--egos", "2", "--every-m", "150", "--ahead-m", "40",
                           "--density", "30", "--route-m", "300", "--period", "40", "--steps", "1", "-s", "3"])
    net = sumolib.net.readNet(NET, withInternal=True)
    size = len(net.getEdges()) + sum(len(e.getLanes()) for e in net.getEdges())
    return bench.soak(o, echo=lambda line: None), size


def test_removed_vehicles_leave_nothing_in_the_cosimulation(run):
    res, _ = run
    left = res["leftovers"]
    assert len(res["seedings"]) >= 4 and left["added"] > 0 and res["egos_used"] > 2   # an ego was replaced
    assert left["removed_by_sumo"] > 0              # the property is tried on vehicles SUMO took out
    assert left["removed_named_in_state"] == 0, left["examples_in_state"]
    # nor in SUMO: their own vTypes and routes went with them (Seeder.fit_type, Seeder.add_on_route)
    assert left["removed_vtypes_left_in_sumo"] == 0 and left["removed_routes_left_in_sumo"] == 0, left
    assert res["periods"][-1]["ours_alive"] == left["alive"]


def test_state_containers_stay_within_the_network_size(run):
    res, size = run
    assert len(res["periods"]) == 3
    for rec in res["periods"]:
        big = {path: n for path, n in rec["state_sizes"].items() if "[" not in path and n > size}
        assert not big, (rec["t"], big, size)


def test_egos_gone_leave_no_entry(run):
    res, _ = run
    assert res["leftovers"]["gone_egos_with_state"] == 0, res["leftovers"]["examples_gone_egos"]
