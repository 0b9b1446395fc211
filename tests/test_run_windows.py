"""`python -m sumo_scendiff.run`'s automatic windows (no --center, no --ego): with a demand they go where
its vehicles are at the seeding time; without one, by the road layout alone (real SUMO, the shipped model)."""
from __future__ import annotations

import json
import subprocess

import pytest

from sumo_scendiff import run as run_cli
from sumo_scendiff.core.tools import sumo_binary
from sumo_scendiff.map.locations import auto_windows
from sumo_scendiff.map.network import Network

pytestmark = pytest.mark.slow   # real runs of the CLI: the fast tier is -m "not slow"

SEED = 1
FAST = ["--scenes", "2", "-s", str(SEED), "--steps", "8"]


@pytest.fixture(scope="module")
def grid5(tmp_path_factory) -> str:
    """netgenerate's 5x5 grid, 100 m blocks (0..400 m): 21 junction candidates, 3 on the bottom row."""
    out = tmp_path_factory.mktemp("grid5") / "grid5.net.xml"
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "5", "--grid.length", "100",
                    "-o", str(out)], check=True, capture_output=True)
    return str(out)


@pytest.fixture(scope="module")
def bottom_row(grid5, tmp_path_factory) -> str:
    """A demand on the bottom row only (y = 0, west to east): a car every 2 s."""
    path = tmp_path_factory.mktemp("row") / "row.rou.xml"
    cars = "".join(f'<vehicle id="r{k}" depart="{2 * k}"><route edges="A0B0 B0C0 C0D0 D0E0"/></vehicle>'
                   for k in range(30))
    path.write_text(f"<routes>{cars}</routes>")
    return str(path)


def _run(args, capsys) -> None:
    code = run_cli.main(run_cli.get_options(args))
    _, err = capsys.readouterr()
    assert code == 0, err


def _windows(out) -> list[dict]:
    return [json.load(open(out / f"scene_{k:03d}" / "scene.json"))["window"] for k in range(2)]


def test_windows_go_where_the_demand_is(grid5, bottom_row, tmp_path, capsys):
    layout = auto_windows(Network.load(grid5), 2, seed=SEED)
    assert any(loc.window.cy != 0.0 for loc in layout)    # the layout alone leaves the busy row
    out = tmp_path / "out"
    _run(["-n", grid5, "-r", bottom_row, "--begin", "40", "--rollout", "2", "-o", str(out)] + FAST, capsys)
    windows = _windows(out)
    assert all(w["cy"] == 0.0 and w["cx"] in (100.0, 200.0, 300.0) for w in windows), windows
    assert windows[0] != windows[1]
    scenes = json.load(open(out / "run.json"))["scenes"]
    assert all(s["existing_vehicles"] > 0 for s in scenes), scenes   # SUMO's own cars at T in each


def test_without_demand_the_layout_decides(grid5, tmp_path, capsys):
    out = tmp_path / "out"
    _run(["-n", grid5, "--rollout", "0", "-o", str(out)] + FAST, capsys)
    layout = auto_windows(Network.load(grid5), 2, seed=SEED)
    assert _windows(out) == [{"cx": loc.window.cx, "cy": loc.window.cy, "yaw": loc.window.yaw,
                              "size": loc.window.size} for loc in layout]
