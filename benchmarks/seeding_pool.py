"""Several seeding benchmark runs taken together: events and agents per method summed over the runs'
nets, and each method's rate over SUMO's own with its 95 % confidence interval.

    python benchmarks/seeding_pool.py runs/seed8.md runs/seed16.md runs/seed8_s1.md runs/seed16_s1.md

A handful of collisions decides the hand-off targets ("≤ SUMO's own per agent"), so a ratio is
printed with the interval it is known to: conditional on the two methods' events together, one
method's count is binomial, and the Clopper–Pearson interval of that share is the exact interval of
the rate ratio (events per agent; the agents of the methods differ in number, not in windows). An
interval that holds 1 is a difference these samples cannot tell from none.

That interval takes every agent as independent; the windows of one net in one run are not (they
start from one traffic state, and an event between two host vehicles repeats in every window that
holds them). So the ratio is also given with a bootstrap over the clusters, each run's net one
(percentile interval of the pooled ratio over resampled clusters; ``--boot`` draws, seeded): the
honest interval when a few nets hold most of the events.
"""
from __future__ import annotations

import argparse
import math
import os
import sys

from scipy.stats import binomtest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

ROLLOUT = "### Rollout:"
KEYS = ("collisions", "teleports", "e-brakes")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", metavar="RUN.md", help="seeding benchmark tables (benchmarks/seeding.py -o)")
    p.add_argument("--level", type=float, default=0.95, help="confidence level of the intervals")
    p.add_argument("--boot", type=int, default=4000, metavar="N",
                   help="draws of the bootstrap over the runs' nets (0: none)")
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="also write the table here")
    return p.parse_args(args)


class InputError(ValueError):
    pass


def read_run(path: str) -> dict[str, dict[str, int]]:
    """Per method, agents and events summed over the run's nets (its per-net rollout rows)."""
    out: dict[str, dict[str, int]] = {}
    for rows in read_nets(path).values():
        for method, d in rows.items():
            row = out.setdefault(method, {"agents": 0, **{k: 0 for k in KEYS}})
            for k, v in d.items():
                row[k] += v
    return out


def read_nets(path: str) -> dict[str, dict[str, dict[str, int]]]:
    """Per net of the run, per method, agents and events (its rollout table's rows)."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    try:
        start = next(i for i, ln in enumerate(lines) if ln.startswith(ROLLOUT))
    except StopIteration:
        raise InputError(f"{path}: no rollout table (not written by benchmarks/seeding.py -o)") from None
    out: dict[str, dict[str, dict[str, int]]] = {}
    group = ""
    for ln in lines[start + 1:]:
        if ln.startswith("###") or (out and not ln.strip()):
            break
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        if len(cells) < 6 or not cells[2].isdigit():
            continue
        group = cells[0] or group            # a net's name on its first row only
        if group.startswith("**all"):        # the runs' own total
            continue
        method, agents = cells[1], int(cells[2])
        row = out.setdefault(group, {}).setdefault(method, {"agents": 0, **{k: 0 for k in KEYS}})
        row["agents"] += agents
        for k, cell in zip(KEYS, cells[3:6]):
            if cell not in ("–", "nan"):
                row[k] += round(float(cell) * agents / 100.0)
    if not any("SUMO" in rows for rows in out.values()):
        raise InputError(f"{path}: the rollout table has no SUMO rows")
    return out


def rate_ratio(a: int, n_a: int, b: int, n_b: int, level: float = 0.95) -> tuple[float, float, float]:
    """(a / n_a) / (b / n_b) and its exact interval at ``level`` (Clopper–Pearson, conditional on a + b)."""
    if a + b == 0 or n_a == 0 or n_b == 0:
        return math.nan, 0.0, math.inf
    ci = binomtest(a, a + b).proportion_ci(confidence_level=level, method="exact")
    odds = lambda p: math.inf if p >= 1.0 else p / (1.0 - p) * n_b / n_a
    ratio = math.inf if b == 0 else (a / n_a) / (b / n_b)
    return ratio, odds(ci.low), odds(ci.high)


def cluster_interval(clusters: list[dict], method: str, key: str, level: float = 0.95, draws: int = 4000,
                     seed: int = 0) -> tuple[float, float]:
    """Percentile interval at ``level`` of ``method``'s rate of ``key`` over SUMO's, pooled, when the
    ``clusters`` (each {method: {"agents", key...}}: one run's net) are drawn again with replacement."""
    import numpy as np
    a = np.array([[c.get(method, {}).get(key, 0), c.get(method, {}).get("agents", 0),
                   c.get("SUMO", {}).get(key, 0), c.get("SUMO", {}).get("agents", 0)] for c in clusters], float)
    if not len(a):
        return 0.0, math.inf
    pick = np.random.default_rng(seed).integers(0, len(a), (draws, len(a)))
    s = a[pick].sum(1)                                   # (draws, 4): each draw's pooled counts
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (s[:, 0] / s[:, 1]) / (s[:, 2] / s[:, 3])
    ratio = np.where(s[:, 2] == 0, np.where(s[:, 0] == 0, np.nan, np.inf), ratio)
    ratio = ratio[~np.isnan(ratio)]
    if not len(ratio):
        return 0.0, math.inf
    tail = 100.0 * (1.0 - level) / 2.0
    return (float(np.percentile(ratio, tail, method="lower")),
            float(np.percentile(ratio, 100.0 - tail, method="higher")))


def _r(v: float) -> str:
    return "∞" if v == math.inf else "–" if v != v else f"{v:.2f}"


def table(runs: dict[str, dict], level: float, clusters: list[dict] | None = None, draws: int = 4000) -> str:
    methods = list(dict.fromkeys(m for r in runs.values() for m in r))
    pooled = {m: {k: sum(r.get(m, {}).get(k, 0) for r in runs.values()) for k in ("agents", *KEYS)}
              for m in methods}
    head = " | ".join(f"{k} (per 100)" for k in KEYS)
    lines = [f"| run | method | agents | {head} |", "|---|---|---|" + "---|" * len(KEYS)]
    for name, r in [*runs.items(), (f"**pooled ({len(runs)})**", pooled)]:
        for k, m in enumerate(methods):
            d = r.get(m)
            if d is None:
                continue
            cells = [f"{d[key]} ({100.0 * d[key] / d['agents']:.2f})" if d["agents"] else "–" for key in KEYS]
            lines.append(f"| {name if k == 0 else ''} | {m} | {d['agents']} | " + " | ".join(cells) + " |")
    pct = f"{100 * level:g} %"
    lines += ["", f"Rate per agent over SUMO's own traffic, pooled, with its {pct} interval:", "",
              "| method | " + " | ".join(KEYS) + " |", "|---|" + "---|" * len(KEYS)]
    ref = pooled["SUMO"]
    for m in methods:
        if m == "SUMO":
            continue
        cells = []
        for key in KEYS:
            ratio, lo, hi = rate_ratio(pooled[m][key], pooled[m]["agents"], ref[key], ref["agents"], level)
            cells.append(f"{_r(ratio)} ({_r(lo)}–{_r(hi)})")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    if clusters:
        lines += ["", f"The same ratios, {pct} interval of a bootstrap over the {len(clusters)} clusters (each run's "
                  f"net: its windows share one traffic state), {draws} draws:", "",
                  "| method | " + " | ".join(KEYS) + " |", "|---|" + "---|" * len(KEYS)]
        for m in methods:
            if m == "SUMO":
                continue
            cells = []
            for key in KEYS:
                ratio = rate_ratio(pooled[m][key], pooled[m]["agents"], ref[key], ref["agents"], level)[0]
                lo, hi = cluster_interval(clusters, m, key, level, draws)
                cells.append(f"{_r(ratio)} ({_r(lo)}–{_r(hi)})")
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(o) -> int:
    try:
        nets = {os.path.basename(p): read_nets(p) for p in o.runs}
        runs = {os.path.basename(p): read_run(p) for p in o.runs}
    except InputError as e:
        print(f"seeding_pool: {e}", file=sys.stderr)
        return 2
    clusters = [rows for per_net in nets.values() for rows in per_net.values()]
    text = table(runs, o.level, clusters if o.boot > 0 else None, o.boot)
    print(text)
    if o.output:
        with open(o.output, "w", encoding="utf-8") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
