"""benchmarks/compare_models.py at toy scale: the shipped model against itself on a tiny network
(the same seeds give the same numbers in both columns), a finished part kept, a failed one named, and
bad input."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, "benchmarks", "compare_models.py")
SHIPPED = os.path.join(REPO, "sumo_scendiff", "weights", "scendiff.pt")
sys.path.insert(0, os.path.join(REPO, "benchmarks"))
from compare_models import spread_rows  # noqa: E402


def _compare(tmp_path, cross_net, *args):
    return subprocess.run([sys.executable, SCRIPT, *args, "-n", cross_net, "--scenes", "6", "--token-windows", "2",
                           "--skip", "density", "handoff", "fill", "--train-data", str(tmp_path / "pool"),
                           "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "cmp"),
                           "-o", str(tmp_path / "t.md")], capture_output=True, text=True)


@pytest.mark.slow
def test_a_model_against_itself_reads_the_same_in_both_columns(tmp_path, cross_net):
    assert subprocess.run([sys.executable, "-m", "sumo_scendiff.data", "-n", cross_net, "-o", str(tmp_path / "pool"),
                           "--scenes", "8", "-s", "9"], capture_output=True).returncode == 0
    res = _compare(tmp_path, cross_net, SHIPPED, SHIPPED, "--names", "a", "b", "--jobs", "2")
    assert res.returncode == 0, res.stderr[-2000:]
    main_table = res.stdout.split("\n\n")[0].splitlines()
    rows = [ln.split("|")[1:-1] for ln in main_table[2:]]
    names = [r[0].strip() for r in rows]
    assert "MMD² joint, own count — cross" in names and "jsd_speed (mean of networks)" in names
    assert all(r[1] == r[2] for r in rows)   # same model, same windows, same seeds
    text = res.stdout
    folder = os.path.basename(os.path.dirname(cross_net))
    tokens_a, tokens_b = text.split(f"tokens/{folder}, a:")[1].split(f"tokens/{folder}, b:")   # partial tokens, per model
    assert "| x,y,speed |" in tokens_a and tokens_a.strip() == tokens_b.strip()
    assert (tmp_path / "t.md").read_text().strip() == text.strip()
    evaluated = tmp_path / "cmp" / "a" / "evaluate" / f"{folder}.json"
    stamp = evaluated.stat().st_mtime_ns
    # a finished part is kept; a half-written one (a run stopped) runs again
    (tmp_path / "cmp" / "b" / "evaluate" / evaluated.name).rename(tmp_path / "cmp" / "b" / "evaluate" / "x.part.json")
    again = _compare(tmp_path, cross_net, SHIPPED, SHIPPED, "--names", "a", "b", "--skip", "tokens", "turns")
    assert again.returncode == 0, again.stderr[-2000:]
    assert evaluated.stat().st_mtime_ns == stamp and (tmp_path / "cmp" / "b" / "evaluate" / evaluated.name).exists()
    assert again.stdout.split("\n\n")[0].splitlines() == main_table


def test_a_failed_part_is_named_and_the_others_run(tmp_path, cross_net):
    broken = tmp_path / "broken.pt"
    broken.write_bytes(b"not a checkpoint")
    res = _compare(tmp_path, cross_net, str(broken), SHIPPED, "--only", "broken", "--skip", "tokens", "turns")
    assert res.returncode == 1 and "Traceback" not in res.stderr.splitlines()[-1]
    assert "broken: evaluate/" in res.stderr and "failed (exit 2)" in res.stderr
    assert not list((tmp_path / "cmp" / "broken" / "evaluate").glob("*.json"))   # nothing that looks finished
    assert not (tmp_path / "cmp" / "scendiff").exists()                          # --only: one side


def test_bad_input_exit_2(tmp_path):
    for args, words in (([str(tmp_path / "none.pt"), SHIPPED], "none.pt: no such model file"),
                        ([SHIPPED, SHIPPED], "two columns named 'scendiff'"),
                        ([SHIPPED, SHIPPED, "--names", "a", "b", "--only", "c"], "--only: c is not one of --names"),
                        ([SHIPPED, SHIPPED, "--names", "a", "b", "-n", str(tmp_path / "no.net.xml")], "no such network")):
        res = subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True)
        assert res.returncode == 2 and words in res.stderr and "Traceback" not in res.stderr


def test_the_spread_verdict_takes_each_rows_direction():
    """A row is worse only beyond the larger range either model has over the seeds, in the row's own
    direction: lower MMD², a count nearer the reference, more networks rising."""
    def rows(mmd, agents, rising):
        return {"MMD² joint — x": (mmd, 0.6), "agents per window — x": (agents, 7.0),
                "density response model: networks rising": (rising, None)}
    seeds = [{"a": rows(0.50, 8.0, 13.0), "b": rows(0.60, 9.5, 13.0)},
             {"a": rows(0.52, 7.5, 12.0), "b": rows(0.61, 6.0, 12.0)}]
    lines = spread_rows(["a", "b"], seeds)
    cells = {ln.split("|")[1].strip(): [c.strip() for c in ln.split("|")[2:-1]] for ln in lines[2:]}
    assert cells["MMD² joint — x"] == ["0.500 / 0.520", "0.600 / 0.610", "+0.095", "0.020", "worse"]
    # |8 - 7|, |7.5 - 7| against |9.5 - 7|, |6 - 7|: b worse by 1.0 on average, within its own range 1.5
    assert cells["agents per window — x"][2:] == ["+1.000", "1.500", ""]
    assert cells["density response model: networks rising"][2:] == ["+0.000", "1.000", ""]
    better = spread_rows(["b", "a"], seeds)
    assert any(ln.startswith("| MMD² joint — x |") and ln.rstrip().endswith("| better |") for ln in better)


def test_spread_of_a_missing_folder_is_one_line(tmp_path):
    res = subprocess.run([sys.executable, SCRIPT, SHIPPED, SHIPPED, "--names", "a", "b", "--spread",
                          str(tmp_path / "nothing")], capture_output=True, text=True)
    assert res.returncode == 2 and "--spread" in res.stderr and "no such comparison folder" in res.stderr
    assert "Traceback" not in res.stderr
