"""A sweep's `{auto = N}` windows: with the entry's demand they go where its vehicles are at the seeding
time, as run's do, the same with one worker or two; without one, by the road layout alone (real SUMO,
the shipped model)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from sumo_scendiff.map.locations import auto_windows
from sumo_scendiff.map.network import Network

from .test_run_windows import bottom_row, grid5  # noqa: F401  (fixtures: the 5x5 grid, cars on its bottom row)

pytestmark = pytest.mark.slow   # real sweeps of the CLI: the fast tier is -m "not slow"

SPEC = """networks = [{entry}]
locations = [{{auto = 2}}]
seeds = 1
steps = 4
rollout = 1.0
"""


def _sweep(entry: str, tmp_path, workers: int, name: str) -> tuple[list[dict], list[dict]]:
    """(each scene's window, each index row) of a sweep of ``entry`` on ``workers`` workers."""
    spec = tmp_path / f"{name}.toml"
    spec.write_text(SPEC.format(entry=entry))
    out = tmp_path / name
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.sweep", "--spec", str(spec), "--out", str(out),
                           "--workers", str(workers), "--no-pictures"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    windows = [json.load(open(out / f"s{k:04d}" / "scene.json"))["window"] for k in range(2)]
    return windows, [json.loads(line) for line in open(out / "index.jsonl")]


def test_auto_windows_go_where_the_demand_is_with_any_worker_count(grid5, bottom_row, tmp_path):
    layout = auto_windows(Network.load(grid5), 2, seed=0)
    assert any(loc.window.cy != 0.0 for loc in layout)    # the layout alone leaves the busy row
    entry = f'{{net = "{grid5}", routes = "{bottom_row}", begin = 40}}'
    one, rows = _sweep(entry, tmp_path, 1, "one")
    assert all(w["cy"] == 0.0 and w["cx"] in (100.0, 200.0, 300.0) for w in one), one
    assert one[0] != one[1]
    assert all(r["existing_vehicles"] > 0 for r in rows), rows   # SUMO's own cars at T in each
    two, _ = _sweep(entry, tmp_path, 2, "two")
    assert two == one


def test_without_demand_the_layout_decides(grid5, tmp_path):
    windows, _ = _sweep(f'"{grid5}"', tmp_path, 1, "bare")
    assert windows == [{"cx": loc.window.cx, "cy": loc.window.cy, "yaw": loc.window.yaw,
                        "size": loc.window.size} for loc in auto_windows(Network.load(grid5), 2, seed=0)]
