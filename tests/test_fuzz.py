"""Mutated inputs (benchmarks/fuzz.py's mutator, seeded): every near-valid token file, sweep spec,
configuration, route, additional and edgeData file ends in success or one documented error in one
line, never a traceback or a hang; the CLI says it in one line with exit 2. File and folder names
with spaces, quotes, ``;``, ``$(…)`` and non-ASCII letters work in `run` and `fill`, and stock SUMO
runs what they export."""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from collections import Counter

import pytest

BENCH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
# a folder name as users and scripts make them: every character a shell or an XML file treats specially
ODD = "my runs 'q' \"d\"; $(touch pwned) é ü"


def _fuzz():
    spec = importlib.util.spec_from_file_location("fuzz", os.path.join(BENCH, "fuzz.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def fuzz(tmp_path_factory):
    mod = _fuzz()
    return mod, mod.build_corpus(str(tmp_path_factory.mktemp("fuzz")))


def test_mutations_are_near_valid_and_seeded(fuzz):
    """The same seed, the same cases; and the mutator keeps most inputs readable (a fuzz whose
    every case is junk tests only the first check)."""
    mod, ctx = fuzz
    first = [open(p, "rb").read() for _, p in mod.cases(ctx, 30, 7)]
    again = [open(p, "rb").read() for _, p in mod.cases(ctx, 30, 7)]
    assert first == again
    assert len(set(first)) > 25


def test_mutated_inputs_end_in_success_or_one_line(fuzz):
    mod, ctx = fuzz
    tally, failures = Counter(), []
    for kind, path in mod.cases(ctx, 200, 0):
        outcome, detail = mod.run_case(ctx, kind, path)
        tally[kind, outcome] += 1
        if outcome in ("traceback", "hang"):
            failures.append(f"{kind} {path}: {detail}")
    assert not failures, "\n".join(failures[:3])
    for kind in mod.KINDS:     # each kind both read and refused: the mutations reach past the first check
        assert tally[kind, "exit0"] and tally[kind, "exit2"], (kind, tally)


@pytest.mark.slow    # the CLI imports the model's libraries before it reads its inputs
@pytest.mark.parametrize("kind", ["tokens", "routes", "edgedata"])
def test_the_cli_answers_a_mutated_input_in_one_line(fuzz, kind, tmp_path):
    """A case the readers refuse, through `python -m sumo_scendiff.run`: one line, exit 2."""
    mod, ctx = fuzz
    path = next(p for k, p in mod.cases(ctx, 300, 3) if k == kind and mod.run_case(ctx, k, p)[0] == "exit2")
    outcome, detail = mod.cli_case(ctx, kind, path, str(tmp_path / "out"))
    assert outcome == "exit2", detail
    assert os.path.basename(path) in detail or "--edge-data" in detail, detail
    assert not (tmp_path / "out" / "scene_000").exists()


@pytest.fixture(scope="module")
def odd_net(tmp_path_factory):
    import sumo
    folder = tmp_path_factory.mktemp("names") / ODD
    folder.mkdir()
    net = folder / "grid ü 'x'.net.xml"
    subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "netgenerate"), "--grid", "--grid.number", "3",
                    "--grid.length", "100", "-o", str(net)], check=True, capture_output=True)
    return net


def _sumo_runs(config) -> None:
    """Stock SUMO runs the exported configuration from another folder (its paths are its own)."""
    import sumo
    p = subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "sumo"), "-c", str(config), "--end", "20"],
                       capture_output=True, text=True, cwd="/")
    assert p.returncode == 0, p.stderr
    assert "Error" not in p.stderr, p.stderr


@pytest.mark.slow
@pytest.mark.parametrize("command", ["run", "fill"])
def test_odd_file_and_folder_names(odd_net, command):
    out = odd_net.parent / f"{command} out; $(echo x) 'é'"
    args = (["--scenes", "1", "--rollout", "2"] if command == "run" else ["--density", "10"])
    p = subprocess.run([sys.executable, "-m", f"sumo_scendiff.{command}", "-n", str(odd_net), "-o", str(out),
                        *args], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert not (odd_net.parent / "pwned").exists() and not os.path.exists("pwned")
    _sumo_runs(out / "scene_000" / "scenario.sumocfg" if command == "run" else out / "scenario.sumocfg")
    if command == "fill":
        _sumo_runs(out / "start.sumocfg")
