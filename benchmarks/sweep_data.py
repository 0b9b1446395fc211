"""Data for benchmarks/sweep.py: the sweep specs it writes (truck / long) and what it reads back from a
sweep's output directory (index.jsonl, ``*.partial``), with the comparison of two indexes.
"""
from __future__ import annotations

import json
import math
import os
import random
from collections import Counter

CITY = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "networks", "city.net.xml"))
TRUCK = {"name": "truck", "agents": [{"x": 12.0, "y": -1.6, "heading": 0.0, "length": 10.5, "width": 2.5,
                                      "speed": 8.0}], "vary": {"final_speed": [0.0, 8.0]}}

# --------------------------------------------------------------------------------------------------
# specs


def write_spec(path: str, name: str, n: int, seed: int, locations: int, p_masks: list[float], seeds: int,
               token_sets: list[dict] | None, rollout: float, steps: int) -> str:
    """The cross product when it has exactly n scenarios; else (more seeds if needed) n of them drawn
    with ``seed``, written as the explicit list (plan order). ``locations`` stays in the spec, so the
    auto windows are the same whichever are drawn."""
    from sumo_scendiff.sweep.spec import load_spec
    data = {"name": name, "networks": [CITY], "locations": [{"auto": locations}], "p_mask": p_masks,
            "seeds": seeds, "steps": steps, "rollout": rollout}
    if token_sets:
        data["token_sets"] = token_sets
    for _ in range(2):   # the second time with enough seeds
        with open(path, "w") as f:
            json.dump(data, f, indent=1)
        full = load_spec(path).scenarios()
        data["seeds"] = max(seeds, math.ceil(n * seeds / len(full)))
    if len(full) != n:
        pick = sorted(random.Random(seed).sample(range(len(full)), n)) if n < len(full) else range(n)
        data["scenarios"] = [{"network": s.network, "location": s.location, "token_set": s.token_set,
                              "p_mask": s.p_mask, "seed": s.seed} for s in (full[k] for k in pick)]
        for key in ("p_mask", "seeds"):
            del data[key]
        with open(path, "w") as f:
            json.dump(data, f, indent=1)
    assert len(load_spec(path).scenarios()) == n
    return path


def truck_spec(o, workdir: str) -> str:
    """speedup and kill: 4 auto locations x the truck (final speed 0 / 8 m/s) x p_mask 0.2 ... 1.0."""
    return write_spec(os.path.join(workdir, f"truck{o.scenarios}.json"), "bench_truck", o.scenarios, o.seed,
                      locations=4, p_masks=[0.2, 0.4, 0.6, 0.8, 1.0], seeds=1, token_sets=[TRUCK],
                      rollout=o.rollout, steps=o.steps)


def long_spec(o, workdir: str) -> str:
    """memory: 5 auto locations x p_mask 0.1 ... 1.0 x 10 seeds, no tokens."""
    return write_spec(os.path.join(workdir, f"long{o.scenarios}.json"), "bench_long", o.scenarios, o.seed,
                      locations=5, p_masks=[round(0.1 * k, 1) for k in range(1, 11)], seeds=10,
                      token_sets=None, rollout=o.rollout, steps=o.steps)


def plan_ids(spec: str) -> list[str]:
    from sumo_scendiff.sweep.spec import load_spec
    return [s.id for s in load_spec(spec).scenarios()]


def granularity_bound(spec: str, workers: int) -> tuple[float, int]:
    """The best speed-up the task split allows (longest-first on ``workers``), and the task count."""
    from sumo_scendiff.sweep.engines import tasks
    from sumo_scendiff.sweep.spec import load_spec
    sizes = sorted((len(batch) for batch, _ in tasks(load_spec(spec).scenarios())), reverse=True)
    load = [0] * workers
    for s in sizes:
        load[load.index(min(load))] += s
    return sum(sizes) / max(load), len(sizes)


# --------------------------------------------------------------------------------------------------
# outputs


def read_index(out: str) -> list[dict]:
    path = os.path.join(out, "index.jsonl")
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def _close(x, y) -> bool:
    if isinstance(x, float) and isinstance(y, float):
        return math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-12)
    return x == y


def compare(a: list[dict], b: list[dict]) -> str:
    """Exactly equal, or which rows and columns differ (and whether only in float rounding)."""
    if a == b:
        return "**yes**"
    if len(a) != len(b):
        return f"**no** ({len(a)} vs {len(b)} rows)"
    bad = [(x, y) for x, y in zip(a, b) if x != y]
    cols = sorted({k for x, y in bad for k in set(x) | set(y) if x.get(k) != y.get(k)})
    rounding = all(_close(x.get(k), y.get(k)) for x, y in bad for k in cols)
    return (f"**no** ({len(bad)} of {len(a)} rows differ; columns: {', '.join(cols)}"
            + ("; only in float rounding, rel. < 1e-9)" if rounding else ")"))


def partial_left(out: str) -> list[str]:
    """``*.partial`` files and folders anywhere under out."""
    left = []
    for d, dirs, files in os.walk(out):
        left += [os.path.relpath(os.path.join(d, n), out) for n in dirs + files if n.endswith(".partial")]
    return left


def status_counts(rows: list[dict]) -> str:
    c = Counter(r["status"] for r in rows)
    return ", ".join(f"{k} {v}" for k, v in sorted(c.items())) or "no index"
