"""benchmarks/fill.py's helpers (no fill, no model): inputs chosen, Spearman, overlaps, options; and
its --speed part's (benchmarks/fill_speed.py) other side, randomTrips + SUMO."""
from __future__ import annotations

import importlib.util
import math
import os
from collections import Counter

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", os.path.join(HERE, "..", "benchmarks", f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def bench():
    return _load("fill")


@pytest.fixture(scope="module")
def speed():
    return _load("fill_speed")


def test_options(bench):
    o = bench.get_options([])
    assert (o.warmup, o.hold, o.density, o.nets) == (600.0, 1800.0, 25.0, None)
    with pytest.raises(SystemExit):
        bench.get_options(["--hold", "30"])     # shorter than the 60-s collision count


def test_spearman_over_edges_with_a_vehicle(bench):
    rho, n = bench.spearman(Counter(a=3, b=2, c=1), Counter(a=5, b=1, d=2))
    assert n == 4 and -1.0 <= rho <= 1.0
    assert bench.spearman(Counter(a=1, b=2, c=3), Counter(a=2, b=4, c=6)) == (pytest.approx(1.0), 3)
    assert math.isnan(bench.spearman(Counter(a=1), Counter(a=1))[0])


def test_overlaps_count_pairs(bench):
    boxes = {"a": (0.0, 0.0, 0.0, 4.0, 2.0), "b": (3.0, 0.0, 0.0, 4.0, 2.0), "c": (20.0, 0.0, 0.0, 4.0, 2.0)}
    assert bench.overlaps(boxes) == 1
    assert bench.overlaps({"a": boxes["a"]}) == 0


def test_inputs_config_else_net_and_routes(bench, diagonal_net, tmp_path):
    import shutil

    from sumo_scendiff.map.network import Network
    d = str(tmp_path)                       # a copy: the session's network folder stays as it is
    diagonal_net = shutil.copy(diagonal_net, os.path.join(d, "diag.net.xml"))
    with open(os.path.join(d, "demand.rou.xml"), "w") as f:
        f.write('<routes><vehicle id="v" depart="5"><route edges="ab"/></vehicle></routes>')
    net = Network.load(diagonal_net)
    flags, scen = bench.inputs(net)
    assert flags[0] == "-n" and flags[2] == "-r" and scen.begin is None
    # a configuration naming a route file that is not there: its other inputs, find_demand's routes
    cfg = os.path.join(d, "a.sumocfg")
    with open(cfg, "w") as f:
        f.write('<configuration><input><net-file value="diag.net.xml"/><route-files value="gone.rou.xml"/>'
                '</input><time><begin value="3"/></time></configuration>')
    flags, scen = bench.inputs(net)
    assert flags[:2] == ["-c", cfg] and flags[2] == "-r" and scen.begin == 3.0
    for f in ("demand.rou.xml", "a.sumocfg"):
        os.remove(os.path.join(d, f))
    assert bench.inputs(net) == (["-n", os.path.abspath(diagonal_net)], None)


def test_random_trips_reach_the_fills_number(bench, speed, grid, tmp_path):
    """The head-to-head's other side: randomTrips.py + SUMO until that many vehicles stand on the
    normal lanes (real tools, a tiny grid)."""
    o = bench.get_options(["--speed", "--step-length", "1"])
    km = sum(ln.length for ln in grid.lanes if ln.car and not ln.edge.startswith(":")) / 1000.0
    r = speed.random_trips_side(grid.path, km, 10, str(tmp_path), o)
    assert r["reached"] and r["vehicles"] >= 10 and r["veh_per_km"] == pytest.approx(r["vehicles"] / km)
    assert 0 < r["simulated_s"] <= speed.RT_LIMIT_S and r["random_trips_s"] > 0
    table = speed.speed_table([{"net": "grid", "after": {"error": ["boom"]}, "random_trips": r}], o)
    assert "randomTrips + SUMO" in table and "failed: ['boom']" in table
