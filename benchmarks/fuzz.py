"""Mutated inputs: near-valid token files, sweep specs, SUMO configurations, route, additional and
edgeData files, each read by the entry point a command reads it with; every case must end in
success or in one of the documented errors with a one-line message (the CLIs' one line and exit 2)
within a time limit: never another exception (a traceback), never a hang.

    python benchmarks/fuzz.py --cases 5000 -s 0          # in process, by kind and outcome
    python benchmarks/fuzz.py --cases 0 --cli 30 -s 0    # cases through `python -m sumo_scendiff.run`

The cases (the valid inputs and their mutations, seeded) are benchmarks/fuzz_inputs.py's; this file
reads them as the commands do and tallies what came of each. tests/test_fuzz.py runs a few hundred;
docs/benchmarks.md has the figures of the large run.
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fuzz_inputs import KINDS, build_corpus, cases  # noqa: E402  (the cases; test_fuzz takes them from here)

LIMIT_S = 30.0         # a case's time limit (SUMO's preflight of a tiny grid takes a fraction of it)
PREFLIGHT_S = 20.0     # SUMO's own load time limit in the preflight, under the case's


class Hang(BaseException):
    """A case ran past its time limit (a BaseException: no product `except Exception` swallows it)."""


# ---------------------------------------------------------------- the entry points

def _network(ctx: dict, path: str):
    from sumo_scendiff.map.network import Network
    cache = ctx.setdefault("networks", {})
    if path not in cache:
        cache[path] = Network.load(path)
    return cache[path]


def _read_scenario(ctx: dict, config=None, routes=(), additional=()) -> None:
    """What `run` does with its -c/-n/-r/-a before generating (sumo_scendiff/run/), up to the seeding time."""
    from sumo_scendiff.data.demand import demand_span, seeding_time
    from sumo_scendiff.sim.preflight import preflight
    from sumo_scendiff.sim.scenario import scenario_from_files
    scen = preflight(scenario_from_files(config, None if config else ctx["net"], routes, additional),
                     timeout=PREFLIGHT_S)
    net = _network(ctx, scen.net)
    if scen.routes:
        span = demand_span(scen.routes, {ln.edge for ln in net.lanes}, scen.additional)
        if span:
            seeding_time(None, scen.begin, span, scen.routes)


def _read_tokens(ctx: dict, path: str) -> None:
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.generation.token_resolve import resolve_tokens
    from sumo_scendiff.tokens.file import load_tokens
    net = _network(ctx, ctx["net"])
    spec = load_tokens(path, net=net)
    w = Window(100.0, 1.6, 0.0)
    agents = resolve_tokens(net, w, spec.for_window(w), spec.source)
    # as generation takes them: encoded, and their exact values in the model's float32 tensors
    from sumo_scendiff.tokens.encoding import agent_tokens_from_dicts
    from sumo_scendiff.tokens.raster import exact_values
    agent_tokens_from_dicts([{k: v for k, v in a.items() if k != "vtype"} for a in agents])
    exact_values([agents], [len(agents)])


def _read_spec(ctx: dict, path: str) -> None:
    from sumo_scendiff.sweep.spec import load_spec
    load_spec(path).scenarios()


def _read_edgedata(ctx: dict, path: str) -> None:
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.map.edgedata import EdgeData
    net = _network(ctx, ctx["net"])
    data = EdgeData.read(path, net)
    for t in (0.0, 150.0, 1e9):
        try:
            data.window_density(net, Window(100.0, 100.0, 0.0), t)
        except Exception as e:        # a time no interval covers is the documented EdgeDataError
            if type(e).__name__ != "EdgeDataError" or "no interval covers" not in str(e):
                raise


READERS = {
    "tokens": _read_tokens,
    "spec": _read_spec,
    "sumocfg": lambda ctx, p: _read_scenario(ctx, config=p),
    "routes": lambda ctx, p: _read_scenario(ctx, routes=[p]),
    "additional": lambda ctx, p: _read_scenario(ctx, routes=[ctx["routes"]], additional=[p]),
    "edgedata": _read_edgedata,
}


def documented_errors() -> dict[str, tuple[type, ...]]:
    """Per kind, the errors the commands turn into one line and exit 2 (run/cli.py, sweep/__main__.py)."""
    from sumo_scendiff.data.demand import DemandError
    from sumo_scendiff.map.edgedata import EdgeDataError
    from sumo_scendiff.map.network import NetworkError
    from sumo_scendiff.sim.scenario import ScenarioError
    from sumo_scendiff.sweep.spec import SpecError
    from sumo_scendiff.tokens.file import TokenFileError
    scenario = (ScenarioError, DemandError, NetworkError)
    return {"tokens": (TokenFileError,), "spec": (SpecError, TokenFileError), "sumocfg": scenario,
            "routes": scenario, "additional": scenario, "edgedata": (EdgeDataError,)}


def _on_alarm(signum, frame):
    raise Hang()


def run_case(ctx: dict, kind: str, path: str, limit: float = LIMIT_S) -> tuple[str, str]:
    """(outcome, detail): "exit0", "exit2" (a documented error, one line), "traceback" (any other
    exception, or a documented one over several lines) or "hang" (past ``limit`` seconds)."""
    expected = ctx.setdefault("errors", documented_errors())[kind]
    old = signal.signal(signal.SIGALRM, _on_alarm)
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        READERS[kind](ctx, path)
        return "exit0", ""
    except Hang:
        return "hang", f"over {limit:g} s"
    except expected as e:
        msg = str(e)
        return ("exit2", msg) if msg and "\n" not in msg else ("traceback", f"not one line: {msg!r}")
    except BaseException:         # a traceback: SystemExit, KeyboardInterrupt and all
        return "traceback", traceback.format_exc()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# ---------------------------------------------------------------- through the CLI

def cli_case(ctx: dict, kind: str, path: str, out: str, limit: float = 300.0) -> tuple[str, str]:
    """The case through `python -m sumo_scendiff.run` (--rollout 0, one scene): (outcome, detail)."""
    args = {"tokens": ["-n", ctx["net"], "--tokens", path], "sumocfg": ["-c", path],
            "routes": ["-n", ctx["net"], "-r", path], "additional": ["-n", ctx["net"], "-r", ctx["routes"],
                                                                     "-a", path],
            "edgedata": ["-n", ctx["net"], "-r", ctx["routes"], "--density", "auto", "--edge-data", path]}[kind]
    cmd = [sys.executable, "-m", "sumo_scendiff.run", *args, "--rollout", "0", "--scenes", "1", "-o", out]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=limit, cwd=ctx["work"])
    except subprocess.TimeoutExpired:
        return "hang", f"over {limit:g} s"
    err = [ln for ln in p.stderr.splitlines() if ln.strip() and "Warning" not in ln]
    if p.returncode == 0:
        return "exit0", ""
    if p.returncode == 2 and len(err) == 1 and "Traceback" not in p.stderr:
        return "exit2", err[0]
    return "traceback", f"exit {p.returncode}: {p.stderr[-2000:]}"


# ---------------------------------------------------------------- the benchmark

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=5000, help="in-process cases")
    ap.add_argument("--cli", type=int, default=0, help="cases through the run CLI (seconds each)")
    ap.add_argument("-s", "--seed", type=int, default=0)
    ap.add_argument("--show", type=int, default=3, help="failures printed in full")
    o = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="scendiff-fuzz-") as work:
        ctx = build_corpus(work)
        tally, failures, t0 = Counter(), [], time.perf_counter()
        for kind, path in cases(ctx, o.cases, o.seed):
            outcome, detail = run_case(ctx, kind, path)
            tally[kind, outcome] += 1
            if outcome in ("traceback", "hang"):
                failures.append((kind, path, detail))
        took = time.perf_counter() - t0
        cli_kinds = tuple(k for k in KINDS if k != "spec")
        for k, (kind, path) in enumerate(cases(ctx, o.cli, o.seed + 1, cli_kinds)):
            outcome, detail = cli_case(ctx, kind, path, os.path.join(work, f"out{k}"))
            tally["cli " + kind, outcome] += 1
            if outcome in ("traceback", "hang"):
                failures.append(("cli " + kind, path, detail))
        _report(tally, failures, o, took, time.perf_counter() - t0 - took)
    return 1 if failures else 0


def _report(tally: Counter, failures: list, o, took: float, cli_took: float) -> None:
    kinds = sorted({k for k, _ in tally}, key=lambda k: (k.startswith("cli"), k))
    outcomes = ("exit0", "exit2", "traceback", "hang")
    print(f"| kind | cases | {' | '.join(outcomes)} |\n|---|---|" + "---|" * len(outcomes))
    for kind in kinds:
        row = [tally[kind, x] for x in outcomes]
        print(f"| {kind} | {sum(row)} | " + " | ".join(map(str, row)) + " |")
    total = [sum(tally[k, x] for k in kinds) for x in outcomes]
    print(f"| all | {sum(total)} | " + " | ".join(map(str, total)) + " |")
    print(f"\nseed {o.seed}: {o.cases} cases in process in {took:.0f} s, {o.cli} through the CLI in "
          f"{cli_took:.0f} s; tracebacks {total[2]}, hangs {total[3]}")
    for kind, path, detail in failures[:o.show]:
        print(f"\n--- {kind} {os.path.basename(path)}\n{detail}")
    counts = Counter(re.sub(r"\d+", "N", d.strip().splitlines()[-1])[:160] for _, _, d in failures)
    for line, n in counts.most_common(20):
        print(f"{n:5d}  {line}")


if __name__ == "__main__":
    sys.exit(main())
