"""benchmarks/seeding_pool.py: the seeding benchmark's own tables read back, pooled, and the rate
ratio's exact interval."""
from __future__ import annotations

import importlib.util
import math
import os
import sys
from collections import Counter
from types import SimpleNamespace

import pytest

from sumo_scendiff.sim.rollout import RolloutStats

BENCH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")


def _load(name):
    sys.path.insert(0, BENCH)
    try:
        spec = importlib.util.spec_from_file_location(name, os.path.join(BENCH, f"{name}.py"))
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(BENCH)


@pytest.fixture(scope="module")
def pool():
    return _load("seeding_pool")


def _method(windows):
    """A method's results over windows of (agents, collisions, teleports, e-brakes)."""
    stats = [RolloutStats(agents=a, collisions=c, teleports=t, emergency_brakes=e, mean_speed=5.0)
             for a, c, t, e in windows]
    return {"stats": stats, "generated": sum(w[0] for w in windows), "dropped": 0, "refused": Counter(),
            "absent": 0, "off_pose": 0, "placed": sum(w[0] for w in windows), "slowed": 0, "fitted": 0}


def _run(tmp_path, name, nets):
    tables = _load("seeding_tables")
    results = [{"net": net, "demand": "own", "windows": len(m["SUMO"]), "kinds": {"signalised": 1},
                "on_road": 10, "seconds": {"warmup": 0.0, "generate": 0.0, "windows": 0.0, "total": 0.0},
                "repeatable": True, "methods": {k: _method(v) for k, v in m.items()}}
               for net, m in nets.items()]
    o = SimpleNamespace(seed=0, windows=2, warmup=600.0, rollout=60.0, step_length=0.5)
    path = tmp_path / name
    path.write_text(tables.tables(results, o, "python benchmarks/seeding.py"), encoding="utf-8")
    return str(path)


def test_reads_the_benchmark_tables_without_their_total(pool, tmp_path):
    a = _run(tmp_path, "a.md", {
        "n1": {"SUMO": [(30, 1, 0, 0), (20, 0, 1, 0)], "Scenario Diffusion": [(25, 2, 0, 1), (15, 0, 0, 0)],
               "Lane-uniform": [(40, 1, 1, 3)]},
        "n2": {"SUMO": [(7, 0, 0, 0)], "Scenario Diffusion": [(3, 1, 0, 0)], "Lane-uniform": [(9, 0, 2, 0)]}})
    run = pool.read_run(a)
    assert run["SUMO"] == {"agents": 57, "collisions": 1, "teleports": 1, "e-brakes": 0}
    assert run["Scenario Diffusion"] == {"agents": 43, "collisions": 3, "teleports": 0, "e-brakes": 1}
    assert run["Lane-uniform"] == {"agents": 49, "collisions": 1, "teleports": 3, "e-brakes": 3}
    b = _run(tmp_path, "b.md", {"n3": {"SUMO": [(10, 1, 0, 0)], "Scenario Diffusion": [(10, 0, 0, 0)],
                                       "Lane-uniform": [(10, 0, 0, 0)]}})
    assert pool.read_run(b)["SUMO"]["agents"] == 10          # one net: no total row
    text = pool.table({"a.md": run, "b.md": pool.read_run(b)}, 0.95)
    assert "| **pooled (2)** | SUMO | 67 | 2 (2.99)" in text


def test_rate_ratio_and_its_exact_interval(pool):
    ratio, lo, hi = pool.rate_ratio(7, 1970, 7, 2529)
    assert ratio == pytest.approx((7 / 1970) / (7 / 2529))
    assert lo < 1.0 < hi                     # 7 events against 7: no difference these samples can tell
    ratio, lo, hi = pool.rate_ratio(100, 1000, 10, 1000)
    assert ratio == pytest.approx(10.0) and 5.0 < lo < 10.0 < hi < 25.0   # Wald on the log: 5.2-19.2; exact wider
    ratio, lo, hi = pool.rate_ratio(0, 100, 5, 100)
    assert ratio == 0.0 and lo == 0.0 and 0.0 < hi < 1.5
    assert pool.rate_ratio(3, 100, 0, 100)[0] == math.inf
    assert math.isnan(pool.rate_ratio(0, 100, 0, 100)[0])


def test_bad_input_one_line_exit_2(pool, tmp_path, capsys):
    assert pool.main(pool.get_options([str(tmp_path / "missing.md")])) == 2
    other = tmp_path / "other.md"
    other.write_text("# not a seeding run\n", encoding="utf-8")
    assert pool.main(pool.get_options([str(other)])) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "missing.md" in err[0] and "no rollout table" in err[1]


def test_bootstrap_over_nets_is_wider_where_one_net_holds_the_events(pool, tmp_path):
    """Ten nets alike but one whose SUMO traffic collides in every window: the exact interval takes
    its repeated events as independent, the bootstrap over nets does not."""
    nets = {f"n{i}": {"SUMO": [(50, 0, 0, 0)], "Scenario Diffusion": [(50, 1 if i < 3 else 0, 0, 0)],
                      "Lane-uniform": [(50, 0, 0, 0)]} for i in range(10)}
    nets["hot"] = {"SUMO": [(50, 30, 0, 0)], "Scenario Diffusion": [(50, 1, 0, 0)], "Lane-uniform": [(50, 0, 0, 0)]}
    path = _run(tmp_path, "hot.md", nets)
    clusters = list(pool.read_nets(path).values())
    assert len(clusters) == 11 and clusters[-1]["SUMO"]["collisions"] == 30
    run = pool.read_run(path)
    ratio, lo, hi = pool.rate_ratio(run["Scenario Diffusion"]["collisions"], run["Scenario Diffusion"]["agents"],
                                    run["SUMO"]["collisions"], run["SUMO"]["agents"])
    blo, bhi = pool.cluster_interval(clusters, "Scenario Diffusion", "collisions")
    assert ratio == pytest.approx(4 / 30) and hi < 1.0          # exact: "fewer than SUMO's", surely
    assert blo <= ratio <= bhi and bhi == math.inf               # without the hot net SUMO has none
    assert pool.cluster_interval(clusters, "Scenario Diffusion", "collisions") == (blo, bhi)   # seeded
    text = pool.table({"hot.md": run}, 0.95, clusters, 500)
    assert "bootstrap over the 11 clusters" in text
