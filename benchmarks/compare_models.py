"""Compare two model files side by side on the rows the README reports, same windows, same seeds.

    python benchmarks/compare_models.py sumo_scendiff/weights/scendiff.pt runs/scendiff/scendiff.pt \\
        --names shipped new --out runs/compare [-o docs/compare.md]

For each model, in turn (each part's result is kept in OUT/NAME/ and not run again):

* ``evaluate``: ``python -m sumo_scendiff.evaluate --tokens`` on the real cities of ../shared/nets:
  the distribution (MMD² joint, agents per window) with the model's own count and told the true
  count, Scenario Dreamer's JSD set against SUMO's own traffic in other windows (the floor), and the
  token tables (match rate per p_mask, speed MAE per token feature set: partial tokens);
* ``density``: ``experiments/density_response.py`` (median relative error of the delivered and
  the drawn density against the request, networks whose medians rise with the request);
* ``turns``: ``experiments/turn_choice.py`` (the turn a token asks where the road offers one).

Then one table: a row per measure, a column per model, and the reference where there is one
(SUMO 2 min later, the JSD floor). The hand-off (benchmarks/seeding.py, ten samples) and the fill
targets (benchmarks/fill.py) take their own runs: docs/evaluation.md gives their commands.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
PARTS = ("evaluate", "density", "turns")
MODEL = "Scenario Diffusion"
TOLD = f"{MODEL} (true count)"


def get_options(args=None):
    from sumo_scendiff.evaluate.__main__ import REAL_CITIES, SHARED_NETS
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("models", nargs=2, metavar="MODEL.pt")
    p.add_argument("--names", nargs=2, default=None, help="column names (default: the files' names)")
    p.add_argument("--out", default=os.path.join(ROOT, "runs", "compare"), help="where each part's results go")
    p.add_argument("-n", "--net-file", dest="nets", action="append", default=None,
                   help="network (repeat); default: the real cities of ../shared/nets")
    p.add_argument("--scenes", type=int, default=200, help="ground-truth windows per network (evaluate)")
    p.add_argument("--token-scenes", type=int, default=100, help="windows per network of the token tables")
    p.add_argument("--windows", type=int, default=24, help="windows per network of the density response")
    p.add_argument("--turn-windows", type=int, default=240, help="recorded windows per city of the turn choice")
    p.add_argument("--train-data", default=None, help="evaluate's Random Log pool (default: evaluate's)")
    p.add_argument("--cache", default=None, help="evaluate's ground-truth cache (default: evaluate's)")
    p.add_argument("--skip", nargs="+", default=[], choices=PARTS, help="parts not to run")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, help="also write the table here (markdown)")
    o = p.parse_args(args)
    for path in o.models:
        if not os.path.isfile(path):
            p.error(f"{path}: no such model file")
    o.names = o.names or [os.path.splitext(os.path.basename(m))[0] for m in o.models]
    if o.names[0] == o.names[1]:
        p.error(f"--names: two columns named {o.names[0]!r}; name them apart")
    o.nets = o.nets or [os.path.join(SHARED_NETS, c) for c in REAL_CITIES if os.path.exists(os.path.join(SHARED_NETS, c))]
    return o


def commands(o, model: str, out: str) -> dict[str, tuple[list[str], str]]:
    """Each part's command line and the file it writes."""
    nets = [a for n in o.nets for a in ("-n", n)]
    ev, dens, turns = (os.path.join(out, f) for f in ("evaluate.json", "density.json", "turns.md"))
    cities = sorted({os.path.basename(os.path.dirname(os.path.abspath(n))) for n in o.nets})
    return {"evaluate": ([sys.executable, "-m", "sumo_scendiff.evaluate", *nets, "--checkpoint", model,
                          "--scenes", str(o.scenes), "--tokens", "--token-scenes", str(o.token_scenes),
                          "-s", str(o.seed), "--json", ev, *_passed(o)], ev),
            "density": ([sys.executable, os.path.join(ROOT, "experiments", "density_response.py"), *nets,
                         "--checkpoint", model, "--windows", str(o.windows), "-s", str(o.seed), "--json", dens], dens),
            "turns": ([sys.executable, os.path.join(ROOT, "experiments", "turn_choice.py"), "--cities", *cities,
                       "--checkpoint", model, "--windows", str(o.turn_windows), "-s", str(o.seed), "-o", turns], turns)}


def _passed(o) -> list[str]:
    return [a for flag, v in (("--train-data", o.train_data), ("--cache", o.cache)) if v for a in (flag, v)]


def run_parts(o) -> dict[str, dict[str, str]]:
    """Run every part not skipped for both models (a part whose file exists is kept); name -> part -> file."""
    files = {}
    for name, model in zip(o.names, o.models):
        out = os.path.join(o.out, name)
        os.makedirs(out, exist_ok=True)
        files[name] = {}
        for part, (cmd, path) in commands(o, os.path.abspath(model), out).items():
            if part in o.skip:
                continue
            if not os.path.exists(path):
                print(f"compare: {name}: {part}", file=sys.stderr, flush=True)
                subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
            files[name][part] = path
    return files


def _mean(values) -> float:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.mean(v)) if v else float("nan")


def evaluate_rows(result: dict) -> dict[str, tuple[float, float | None]]:
    """measure -> (the model's value, the reference's) from one evaluate --json."""
    dist, rows = result["distribution"], {}
    for r in dist + [None]:
        where = r["net"] if r else "mean"
        pick = (lambda method, key: r["methods"].get(method, {}).get(key)) if r else \
            (lambda method, key: _mean(x["methods"].get(method, {}).get(key) for x in dist))
        rows[f"MMD² joint, own count — {where}"] = (pick(MODEL, "mmd2_joint"), pick("SUMO 2 min later", "mmd2_joint"))
        rows[f"MMD² joint, told the count — {where}"] = (pick(TOLD, "mmd2_joint"), pick("Lane-uniform (true count)", "mmd2_joint"))
        rows[f"agents per window — {where}"] = (pick(MODEL, "agents_per_scene"), pick("Ground truth", "agents_per_scene"))
    jsd = [r["jsd"] for r in dist if "jsd" in r]
    for key in (jsd[0][MODEL] if jsd else {}):
        rows[f"{key} (mean of networks)"] = (_mean(j[MODEL][key] for j in jsd),
                                              _mean(j["SUMO, other windows"][key] for j in jsd))
    for net, tables in result.get("tokens", {}).items():
        for x in tables["speed"]:
            rows[f"tokens {x['features']}: match rate — {net}"] = (x["match_rate"], None)
            rows[f"tokens {x['features']}: speed MAE (m/s) — {net}"] = (x["speed_mae"], None)
    return rows


def density_rows(rows: list[dict]) -> dict[str, tuple[float, None]]:
    out = {}
    for mode in [k for k in rows[0] if isinstance(rows[0][k], dict)] if rows else []:
        out[f"density response {mode}: median relative error"] = (
            float(np.median([e for r in rows for e in r[mode]["rel_error_median"]])), None)
        out[f"density response {mode}: networks rising"] = (float(sum(r[mode]["monotone"] for r in rows)), None)
    return out


def table(names: list[str], files: dict[str, dict[str, str]]) -> str:
    """The side-by-side markdown table (and the turn-choice tables as written)."""
    rows: dict[str, dict[str, tuple]] = {}
    for name in names:
        f = files[name]
        got = {}
        if "evaluate" in f:
            with open(f["evaluate"]) as fh:
                got.update(evaluate_rows(json.load(fh)))
        if "density" in f:
            with open(f["density"]) as fh:
                got.update(density_rows(json.load(fh)))
        for key, v in got.items():
            rows.setdefault(key, {})[name] = v
    lines = [f"| measure | {' | '.join(names)} | reference |", "|---|" + "---|" * (len(names) + 1)]
    for key, by in rows.items():
        ref = next((v[1] for v in by.values() if v[1] is not None), None)
        cells = [_fmt(by[n][0]) if n in by else "–" for n in names]
        lines.append(f"| {key} | {' | '.join(cells)} | {_fmt(ref)} |")
    for name in names:
        if "turns" in files[name]:
            with open(files[name]["turns"]) as fh:
                lines += ["", f"Turn choice, {name}:", "", fh.read().strip()]
    return "\n".join(lines)


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    return f"{v:.3f}" if abs(v) < 100 else f"{v:.0f}"


def main(o) -> int:
    files = run_parts(o)
    text = table(o.names, files)
    print(text)
    if o.output:
        with open(o.output, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
