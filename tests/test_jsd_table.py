"""benchmarks/jsd_table.py: evaluate's JSD rows as the results table (the fleet's row where there is one)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, "benchmarks", "jsd_table.py")
FEATURES = ("speed", "nearest", "lane_heading", "lane_distance", "length", "width")


def _jsd(base: float) -> dict:
    return {f"jsd_{k}": base for k in FEATURES} | {"collision": 0.0}


def test_the_table_takes_the_fleets_row_and_the_floor(tmp_path):
    src = tmp_path / "ev"
    src.mkdir()
    with_demand = {"net": "a", "jsd": {"SUMO, other windows": _jsd(1.0), "Scenario Diffusion": _jsd(60.0),
                                       "Scenario Diffusion, the scenario's fleet": _jsd(1.5)}}
    without = {"net": "b", "jsd": {"SUMO, other windows": _jsd(0.0), "Scenario Diffusion": _jsd(3.0)}}
    (src / "a.json").write_text(json.dumps({"distribution": [with_demand]}))
    (src / "b.json").write_text(json.dumps({"distribution": [without]}))
    out = tmp_path / "jsd.json"
    res = subprocess.run([sys.executable, SCRIPT, "--from", str(src), "-o", str(out)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    a, b = json.loads(out.read_text())["rows"]
    assert a["fleet"] == "scenario's" and a["speed"] == "1.50 / 1.00 (1.5×)"
    assert b["fleet"] == "model's" and b["length"] == "3.00 / 0.00 (inf×)"


def test_nothing_to_read_is_one_line(tmp_path):
    res = subprocess.run([sys.executable, SCRIPT, "--from", str(tmp_path), "-o", str(tmp_path / "j.json")],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "no evaluate JSON files" in res.stderr and "Traceback" not in res.stderr
