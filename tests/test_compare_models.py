"""benchmarks/compare_models.py at toy scale: the shipped model against itself on a tiny network
(the same seeds give the same numbers in both columns), and bad input."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, "benchmarks", "compare_models.py")
SHIPPED = os.path.join(REPO, "sumo_scendiff", "weights", "scendiff.pt")


@pytest.mark.slow
def test_a_model_against_itself_reads_the_same_in_both_columns(tmp_path, cross_net):
    pool = tmp_path / "pool"
    assert subprocess.run([sys.executable, "-m", "sumo_scendiff.data", "-n", cross_net, "-o", str(pool),
                           "--scenes", "8", "-s", "9"], capture_output=True).returncode == 0
    res = subprocess.run([sys.executable, SCRIPT, SHIPPED, SHIPPED, "--names", "a", "b", "-n", cross_net,
                          "--scenes", "6", "--token-scenes", "2", "--skip", "density", "turns",
                          "--train-data", str(pool), "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "cmp"),
                          "-o", str(tmp_path / "t.md")], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    rows = [ln.split("|")[1:-1] for ln in res.stdout.splitlines()[2:] if ln.startswith("|")]
    names = [r[0].strip() for r in rows]
    assert "MMD² joint, own count — cross" in names and "jsd_speed (mean of networks)" in names
    assert any(n.startswith("tokens ") for n in names)
    assert all(r[1] == r[2] for r in rows)          # same model, same windows, same seeds
    assert (tmp_path / "t.md").read_text().strip() == res.stdout.strip()


def test_bad_input_exit_2(tmp_path):
    for args, words in (([str(tmp_path / "none.pt"), SHIPPED], "none.pt: no such model file"),
                        ([SHIPPED, SHIPPED], "two columns named 'scendiff'")):
        res = subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True)
        assert res.returncode == 2 and words in res.stderr and "Traceback" not in res.stderr
