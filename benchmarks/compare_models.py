"""Compare two model files side by side on the rows the README reports, same windows, same seeds.

    python benchmarks/compare_models.py sumo_scendiff/weights/scendiff.pt OUT/scendiff.pt \\
        --names shipped new --out compare [--jobs 2] [-o docs/compare.md]

Each model's parts are separate runs of the commands docs/evaluation.md gives, one file each under
OUT/NAME/ (written under a temporary name and renamed when the run ends well, so a part stopped half
way runs again and a finished one is kept): a long comparison resumes where it stopped, and one model's
side can run ahead of the other's from the same tree.

* ``evaluate/CITY``: ``python -m sumo_scendiff.evaluate --scenes 100 -n NET`` per real city: the
  distribution (MMD² joint, agents per window) with the model's own count and told the true count,
  and Scenario Dreamer's JSD set against SUMO's own traffic in other windows (the floor);
* ``density``: ``experiments/density_response.py --windows 16`` (median error of the delivered and
  the drawn density against the request, networks whose medians rise with the request);
* ``tokens/CITY``: ``experiments/user_tokens.py --windows 30``: partial tokens as users write them,
  per kind, drawn and delivered;
* ``turns``: ``experiments/turn_choice.py`` (the turn a token asks where the road offers one);
* ``handoff/S``: ``benchmarks/seeding.py --windows 16 -s S`` for ten seeds, pooled by
  ``benchmarks/seeding_pool.py`` (placement, collisions, teleports, braking beside SUMO's own);
* ``fill``: ``benchmarks/fill.py`` on networks/city.net.xml at 25 veh/km (vehicles placed, overlaps,
  what stock SUMO makes of them, CPU);
* ``token-tables/CITY`` (``--token-tables``): the paper's tables 2, 3 and E.2 (evaluate ``--tokens``).

Then one table: a row per measure, a column per model, and the reference where there is one (SUMO
2 min later, Lane-uniform told the count, the JSD floor), followed by each part's own tables.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from sumo_scendiff.evaluate.__main__ import FLEET, FLOOR, REAL_CITIES, SHARED_NETS

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
PARTS = ("evaluate", "density", "tokens", "turns", "handoff", "fill")
MODEL = "Scenario Diffusion"
TOLD = f"{MODEL} (true count)"


@dataclass(frozen=True)
class Part:
    """One run of one model: ``cmd`` writes ``path`` (given the temporary name ``tmp``)."""
    model: str
    name: str
    cmd: tuple[str, ...]
    path: str

    @property
    def tmp(self) -> str:
        stem, ext = os.path.splitext(self.path)
        return f"{stem}.part{ext}"

    @property
    def log(self) -> str:
        return os.path.join(os.path.dirname(self.path), "logs", os.path.basename(self.path) + ".log")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("models", nargs=2, metavar="MODEL.pt")
    p.add_argument("--names", nargs=2, default=None, help="column names (default: the files' names)")
    p.add_argument("--out", default="compare", help="where each part's results go (OUT/NAME/...)")
    p.add_argument("-n", "--net-file", dest="nets", action="append", default=None,
                   help="network (repeat); default: the real cities of ../shared/nets")
    p.add_argument("--scenes", type=int, default=100, help="ground-truth windows per network (evaluate)")
    p.add_argument("--windows", type=int, default=16, help="windows per network of the density response and hand-off")
    p.add_argument("--token-windows", type=int, default=30, help="recorded windows per city of the partial tokens")
    p.add_argument("--turn-windows", type=int, default=240, help="recorded windows per city of the turn choice")
    p.add_argument("--seeds", type=int, default=10, help="hand-off samples (seeds 0..N-1)")
    p.add_argument("--token-tables", action="store_true", help="also the paper's token tables (evaluate --tokens)")
    p.add_argument("--token-scenes", type=int, default=50, help="windows per network of the token tables")
    p.add_argument("--train-data", default=None, help="evaluate's Random Log pool (default: evaluate's)")
    p.add_argument("--cache", default=None, help="evaluate's ground-truth cache (default: evaluate's)")
    p.add_argument("--skip", nargs="+", action="extend", default=[], choices=PARTS, help="parts not to run")
    p.add_argument("--only", nargs="+", default=None, metavar="NAME", help="run these models' parts only "
                   "(one side ahead of the other); the table is drawn when both sides are there")
    p.add_argument("-j", "--jobs", type=int, default=1, help="parts run at once (each one process)")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, help="also write the table here (markdown)")
    p.add_argument("--spread", default=None, metavar="OUT2", help="the --out of the same comparison at another "
                   "seed: each row at both seeds, its run-to-run spread and whether the second model is worse "
                   "beyond it (the rows of finished parts)")
    o = p.parse_args(args)
    for path in o.models:
        if not os.path.isfile(path):
            p.error(f"{path}: no such model file")
    o.names = o.names or [os.path.splitext(os.path.basename(m))[0] for m in o.models]
    if o.names[0] == o.names[1]:
        p.error(f"--names: two columns named {o.names[0]!r}; name them apart")
    if o.only and set(o.only) - set(o.names):
        p.error(f"--only: {', '.join(sorted(set(o.only) - set(o.names)))} is not one of --names")
    if o.jobs < 1 or o.seeds < 1:
        p.error("--jobs and --seeds must be >= 1")
    if o.spread and not os.path.isdir(o.spread):
        p.error(f"--spread {o.spread}: no such comparison folder")
    o.explicit = bool(o.nets)   # -n given: every part on those networks; else each part's own default set
    o.nets = [os.path.abspath(n) for n in o.nets] if o.nets else \
        [os.path.join(SHARED_NETS, c) for c in REAL_CITIES if os.path.exists(os.path.join(SHARED_NETS, c))]
    for n in o.nets:
        if not os.path.isfile(n):
            p.error(f"-n {n}: no such network file")
    return o


def city(net: str) -> str:
    """A network's folder name: the real cities' names (resco_cologne1, wildau...)."""
    return os.path.basename(os.path.dirname(os.path.abspath(net)))


@functools.lru_cache(maxsize=None)   # parts() is listed again for every table drawn
def _has_demand(net: str) -> bool:
    """A demand of its own beside the network, as evaluate and user_tokens find it (data.demand.find_demand)."""
    from sumo_scendiff.data.demand import find_demand
    from sumo_scendiff.map.network import Network
    return find_demand(Network.load(net)) is not None


def parts(o, name: str, model: str) -> list[Part]:
    """Every run of one model, in the order they are run."""
    out, py, m = os.path.join(os.path.abspath(o.out), name), sys.executable, os.path.abspath(model)
    seed = ("-s", str(o.seed))
    pool = [a for flag, v in (("--train-data", o.train_data), ("--cache", o.cache)) if v for a in (flag, v)]
    cache = ("--cache", o.cache) if o.cache else ()
    nets = tuple(a for n in o.nets for a in ("-n", n)) if o.explicit else ()
    got: list[Part] = []
    if "evaluate" not in o.skip:
        got += [Part(name, f"evaluate/{city(n)}", (py, "-m", "sumo_scendiff.evaluate", "-n", n, "--checkpoint", m,
                     "--scenes", str(o.scenes), *seed, *pool, "--json", "{tmp}"),
                     os.path.join(out, "evaluate", f"{city(n)}.json")) for n in o.nets]
    if "density" not in o.skip:
        got.append(Part(name, "density", (py, os.path.join(ROOT, "experiments", "density_response.py"), *nets,
                        "--checkpoint", m, "--windows", str(o.windows), *seed, "--json", "{tmp}"),
                        os.path.join(out, "density.json")))
    with_demand = [n for n in o.nets if o.explicit or _has_demand(n)]   # user_tokens' default: cities with demand
    if "tokens" not in o.skip:
        got += [Part(name, f"tokens/{city(n)}", (py, os.path.join(ROOT, "experiments", "user_tokens.py"),
                     "-n", n, "--checkpoint", m, "--windows", str(o.token_windows), *seed, *cache,
                     "-o", "{tmp}"), os.path.join(out, "tokens", f"{city(n)}.md")) for n in with_demand]
    if "turns" not in o.skip and not o.explicit:   # turn_choice reads the real cities' folders
        got.append(Part(name, "turns", (py, os.path.join(ROOT, "experiments", "turn_choice.py"), "--cities",
                        *[city(n) for n in with_demand], "--checkpoint", m, "--windows", str(o.turn_windows),
                        *seed, *cache, "-o", "{tmp}"), os.path.join(out, "turns.md")))
    if "handoff" not in o.skip:
        got += [Part(name, f"handoff/{s}", (py, os.path.join(ROOT, "benchmarks", "seeding.py"), *nets, "--checkpoint", m,
                     "--windows", str(o.windows), "-s", str(s), "-o", "{tmp}"),
                     os.path.join(out, "handoff", f"{s}.md")) for s in range(o.seeds)]
    if "fill" not in o.skip:
        got.append(Part(name, "fill", (py, os.path.join(ROOT, "benchmarks", "fill.py"), "-n",
                        os.path.join(ROOT, "networks", "city.net.xml"), "--density", "25", "--hold", "300",
                        "--checkpoint", m, *seed, "-o", "{tmp}"), os.path.join(out, "fill.md")))
    if o.token_tables:
        got += [Part(name, f"token-tables/{city(n)}", (py, "-m", "sumo_scendiff.evaluate", "-n", n, "--checkpoint", m,
                     "--scenes", str(o.token_scenes), "--tokens", "--token-scenes", str(o.token_scenes), *seed,
                     *pool, "--json", "{tmp}"), os.path.join(out, "token-tables", f"{city(n)}.json")) for n in o.nets]
    return got


def finished_parts(o, name: str, model: str) -> list[Part]:
    """The model's parts whose files are there, skipped this time or not (``--skip``: not to run)."""
    return [p for p in parts(argparse.Namespace(**{**vars(o), "skip": []}), name, model) if os.path.exists(p.path)]


def run_part(part: Part) -> str | None:
    """Run one part unless its file is there; None when it ended well, else the line saying why not."""
    if os.path.exists(part.path):
        return None
    os.makedirs(os.path.dirname(part.log), exist_ok=True)
    cmd = [a.replace("{tmp}", part.tmp) for a in part.cmd]
    with open(part.log, "w") as log:
        log.write(" ".join(cmd) + "\n")
        log.flush()
        res = subprocess.run(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    if res.returncode != 0 or not os.path.exists(part.tmp):
        return f"{part.model}: {part.name} failed (exit {res.returncode}): {part.log}"
    os.replace(part.tmp, part.path)
    return None


def run_parts(o) -> list[str]:
    """Run every part of the models asked (``--only``), ``--jobs`` at a time; the failures' lines."""
    from tqdm import tqdm
    todo = [p for name, model in zip(o.names, o.models) if not o.only or name in o.only
            for p in parts(o, name, model)]
    failed = []
    with ThreadPoolExecutor(o.jobs) as pool, tqdm(total=len(todo), unit="part", desc="compare") as bar:
        for part, why in zip(todo, pool.map(run_part, todo)):
            bar.set_postfix_str(f"{part.model}: {part.name}")
            bar.update(1)
            if why:
                failed.append(why)
                tqdm.write(why, file=sys.stderr)
    return failed


def _mean(values) -> float:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.mean(v)) if v else float("nan")


def evaluate_rows(dist: list[dict]) -> dict[str, tuple[float, float | None]]:
    """measure -> (the model's value, the reference's) from evaluate's distribution results."""
    rows = {}
    for r in dist + [None]:
        where = r["net"] if r else "mean"
        pick = (lambda method, key: r["methods"].get(method, {}).get(key)) if r else \
            (lambda method, key: _mean(x["methods"].get(method, {}).get(key) for x in dist))
        rows[f"MMD² joint, own count — {where}"] = (pick(MODEL, "mmd2_joint"), pick("SUMO 2 min later", "mmd2_joint"))
        rows[f"MMD² joint, told the count — {where}"] = (pick(TOLD, "mmd2_joint"), pick("Lane-uniform (true count)", "mmd2_joint"))
        rows[f"agents per window — {where}"] = (pick(MODEL, "agents_per_scene"), pick("Ground truth", "agents_per_scene"))
    for told, ref in ((MODEL, None), (TOLD, "Lane-uniform (true count)")):
        for key in ("mmd2_position", "mmd2_heading", "mmd2_velocity"):
            if ref:   # the target: every per-city MMD² told the count below Lane-uniform's told the same
                misses = sum(1 for r in dist if (r["methods"].get(told, {}).get(key) or 0)
                             >= (r["methods"].get(ref, {}).get(key) or float("inf")))
                rows[f"{key}, told the count: cities not below Lane-uniform told it"] = (float(misses), 0.0)
    jsd = [r["jsd"] for r in dist if "jsd" in r]
    for key in (jsd[0][MODEL] if jsd else {}):
        floor = _mean(j[FLOOR][key] for j in jsd)
        rows[f"{key} (mean of networks)"] = (_mean(j[MODEL][key] for j in jsd), floor)
        fleet = [j[MODEL + FLEET][key] for j in jsd if MODEL + FLEET in j]
        if fleet:   # the cities with a demand: the sizes SUMO's vehicles get from the scenario's vTypes
            rows[f"{key}, the scenario's fleet (mean of {len(fleet)} networks with a demand)"] = (
                _mean(fleet), _mean(j[FLOOR][key] for j in jsd if MODEL + FLEET in j))
        if key != "collision":   # the target: every JSD within 2x SUMO's own floor (the fleet's where run gives it)
            beyond = sum(j[MODEL + FLEET if MODEL + FLEET in j else MODEL][key] > 2.0 * j[FLOOR][key] + 1e-9
                         for j in jsd)
            rows[f"{key}: networks beyond 2× the floor (of {len(jsd)})"] = (float(beyond), 0.0)
    return rows


def token_table_rows(tokens: dict) -> dict[str, tuple[float, None]]:
    rows = {}
    for net, tables in tokens.items():
        for x in tables["speed"]:
            rows[f"token tables {x['features']}: match rate — {net}"] = (x["match_rate"], None)
            rows[f"token tables {x['features']}: speed MAE (m/s) — {net}"] = (x["speed_mae"], None)
    return rows


def density_rows(rows: list[dict]) -> dict[str, tuple[float, None]]:
    out = {}
    for mode in [k for k in rows[0] if isinstance(rows[0][k], dict)] if rows else []:
        out[f"density response {mode}: median relative error"] = (
            float(np.median([e for r in rows for e in r[mode]["rel_error_median"]])), None)
        out[f"density response {mode}: networks rising"] = (float(sum(r[mode]["monotone"] for r in rows)), None)
    return out


def _read_json(path: str):
    with open(path) as f:
        return json.load(f)


def model_rows(o, name: str, model: str) -> dict[str, tuple]:
    """Every numeric row of one model's finished parts."""
    done = finished_parts(o, name, model)
    dist = [r for p in done if p.name.startswith("evaluate/") for r in _read_json(p.path)["distribution"]]
    rows = evaluate_rows(dist) if dist else {}
    for p in done:
        if p.name == "density":
            rows.update(density_rows(_read_json(p.path)))
        elif p.name.startswith("token-tables/"):
            rows.update(token_table_rows(_read_json(p.path)["tokens"]))
    return rows


def pooled_handoff(o, name: str, model: str) -> str | None:
    """seeding_pool.py over the model's finished hand-off samples."""
    files = [p.path for p in finished_parts(o, name, model) if p.name.startswith("handoff/")]
    if not files:
        return None
    res = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "seeding_pool.py"), *files],
                         cwd=ROOT, capture_output=True, text=True)
    return f"{len(files)} samples:\n\n{res.stdout.strip()}" if res.returncode == 0 else None


def table(o) -> str:
    """The side-by-side markdown table, then each model's markdown parts."""
    got = {name: model_rows(o, name, model) for name, model in zip(o.names, o.models)}
    keys = list(dict.fromkeys(k for rows in got.values() for k in rows))
    lines = [f"| measure | {' | '.join(o.names)} | reference |", "|---|" + "---|" * (len(o.names) + 1)]
    for key in keys:
        ref = next((got[n][key][1] for n in o.names if key in got[n] and got[n][key][1] is not None), None)
        cells = [_fmt(got[n][key][0]) if key in got[n] else "–" for n in o.names]
        lines.append(f"| {key} | {' | '.join(cells)} | {_fmt(ref)} |")
    for name, model in zip(o.names, o.models):
        pool = pooled_handoff(o, name, model)
        if pool:
            lines += ["", f"Hand-off, {name}, {pool}"]
        for p in finished_parts(o, name, model):
            if p.path.endswith(".md") and not p.name.startswith("handoff/") and os.path.exists(p.path):
                with open(p.path) as fh:
                    lines += ["", f"{p.name}, {name}:", "", fh.read().strip()]
    return "\n".join(lines)


def _badness(key: str, value: float, ref: float | None) -> float:
    """Larger is worse: the distance to the reference for a count, the negative for a count of rising
    networks, else the value itself (MMD², JSD, errors, misses)."""
    if key.startswith("agents per window"):
        return abs(value - ref) if ref is not None else float("nan")
    return -value if key.endswith("networks rising") else value


def spread_rows(names: list[str], seeds: list[dict[str, dict]]) -> list[str]:
    """One markdown row per measure both models have at both seeds: the values, the second model's
    mean badness over the first's, the spread (the larger range of the two models over the seeds) and
    ``worse`` where the difference is beyond it. ``seeds``: per seed, model name -> model_rows."""
    a, b = names
    lines = [f"| measure | {a} (per seed) | {b} (per seed) | {b} worse by (mean) | spread | verdict |",
             "|---|---|---|---|---|---|"]
    keys = [k for k in seeds[0].get(a, {}) if all(k in s.get(n, {}) for s in seeds for n in names)]
    for key in keys:
        got = {n: [s[n][key] for s in seeds] for n in names}
        bad = {n: [_badness(key, v, ref) for v, ref in got[n]] for n in names}
        if not all(np.isfinite(x) for n in names for x in bad[n]):
            continue
        worse_by = float(np.mean(bad[b]) - np.mean(bad[a]))
        spread = max(float(np.ptp(bad[n])) for n in names)
        verdict = "worse" if worse_by > spread else ("better" if -worse_by > spread else "")
        cells = [" / ".join(_fmt(v) for v, _ in got[n]) for n in names]
        lines.append(f"| {key} | {cells[0]} | {cells[1]} | {worse_by:+.3f} | {spread:.3f} | {verdict} |")
    return lines


def spread_table(o) -> str:
    """The rows of this comparison and of ``--spread``'s (the same comparison at another seed)."""
    seeds = []
    for out in (o.out, o.spread):
        seeds.append({name: model_rows(argparse.Namespace(**{**vars(o), "out": out}), name, model)
                      for name, model in zip(o.names, o.models)})
    return "\n".join([f"Run-to-run spread: this comparison (-s {o.seed}) and --spread's, the rows of the parts "
                      "finished in both", ""] + spread_rows(o.names, seeds))


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    return f"{v:.3f}" if abs(v) < 100 else f"{v:.0f}"


def main(o) -> int:
    failed = run_parts(o)
    text = table(o)
    if o.spread:
        text += "\n\n" + spread_table(o)
    print(text)
    if o.output:
        with open(o.output, "w") as f:
            f.write(text + "\n")
    for why in failed:
        print(f"compare_models.py: {why}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
