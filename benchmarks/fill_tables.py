"""benchmarks/fill.py's tables: what the fill benchmark measured (bench_net's records) as markdown,
each figure beside its target (printed, not asserted), and Spearman's rho of two per-edge counts.

    text = tables(results, o, command)     # per network its table, then the cost table
"""
from __future__ import annotations

import math
from collections import Counter

ROLLOUT = 60.0      # s after the start in which collisions and teleports are counted
FLOOR = 120.0       # s: SUMO's own counts at T against its own at T + FLOOR
SPREAD = 30.0       # s before T over which SUMO's own count is shown (how much it swings)
NEAR = 0.5          # m: a vehicle "at its fill.json pose"


def spearman(a: Counter, b: Counter) -> tuple[float, int]:
    """Spearman's rho of two per-edge counts over the edges with a vehicle in either, and how many."""
    from scipy.stats import spearmanr
    edges = sorted(set(a) | set(b))
    x, y = [a.get(e, 0) for e in edges], [b.get(e, 0) for e in edges]
    if len(edges) < 3 or len(set(x)) < 2 or len(set(y)) < 2:
        return float("nan"), len(edges)
    return float(spearmanr(x, y)[0]), len(edges)


def _nan(v) -> bool:
    return v is None or math.isnan(v)


def _f(v, fmt="{:.2f}") -> str:
    return "–" if _nan(v) else fmt.format(v)


def _met(ok) -> str:
    return "–" if ok is None else ("yes" if ok else "**no**")


def _within(a, b, pct: float):
    """(|a - b| <= pct % of b, or None; the difference in %)."""
    d = 100.0 * (a - b) / b if b else float("nan")
    return (None if _nan(d) else abs(d) <= pct), f"{_f(d, '{:+.0f} %')}"


def demand_table(r: dict, o) -> list[str]:
    s, f, doc = r["sumo"], r["fill"], r["doc"]
    at_s, at_f = s["at"], f["at"]
    rho, n = spearman(at_f["edges"], at_s["edges"])
    floor, nf = spearman(s["floor"]["edges"], at_s["edges"])
    ok_n, d_n = _within(at_f["n"], at_s["n"], 10)
    ok_h, d_h = _within(f["hold"]["n"], s["hold"]["n"], 15)
    p = f["portable"]
    est = doc["density"].get("en_route")
    rows = [
        ("vehicles on the network at T", f"{at_s['n']} (T−{SPREAD:g} s…T: {s['spread'][0]}–{s['spread'][1]}; "
         f"at T+{FLOOR:g} s: {s['floor']['n']})", f"{at_f['n']} ({d_n}; fill.json {doc['summary']['vehicles']}"
         + (f", demand estimate {est} en route" if est is not None else "") + ")", "±10 % of SUMO's", _met(ok_n)),
        ("per-edge counts: Spearman against SUMO's at T", f"floor {_f(floor)} (T vs T+{FLOOR:g} s, {nf} edges)",
         f"{_f(rho)} ({n} edges)", "≥ floor", _met(None if _nan(rho) or _nan(floor) else rho >= floor)),
        (f"collisions / 100 in the first {ROLLOUT:g} s", f"{_f(s['collisions'])} ({s['collision_events']})",
         f"{_f(f['collisions'])} ({f['collision_events']})", "≤ SUMO's", _met(f["collisions"] <= s["collisions"])),
        (f"teleports / 100 in the first {ROLLOUT:g} s", f"{_f(s['teleports'])} ({s['teleport_events']})",
         f"{_f(f['teleports'])} ({f['teleport_events']})", "≤ SUMO's", _met(f["teleports"] <= s["teleports"])),
        (f"vehicles at T + {o.hold:g} s", s["hold"]["n"], f"{f['hold']['n']} ({d_h})", "±15 % of SUMO's",
         _met(ok_h)),
    ] + portable_rows(f) + [
        ("the demand's own vehicles in the fill; driving their own route on", "–",
         f"{doc['summary'].get('demand_vehicles', 0)}; {doc['summary'].get('demand_routes_followed', 0)}", "–", "–"),
        ("boxes overlapping at start (pairs)", s["overlaps"], f"state {f['overlaps']}, portable {p['overlaps']}",
         "–", "–"),
        ("wall time (s)", f"warm-up {s['wall']:.2f}", f"fill {r['fill_wall']:.1f} "
         f"({r['fill_wall'] / max(doc['summary']['car_lane_km'], 1e-9):.1f} s/km)", "–", "–")]
    head = [f"### {r['net']}: T = {r['T']:g} s (begin {r['begin']:g} + {o.warmup:g} s), `{r['inputs']}`", "",
            f"Fill: `{r['command']}`", "", "| metric | SUMO's own | fill | target | met |", "|---|---|---|---|---|"]
    return head + [f"| {a} | {b} | {c} | {t} | {m} |" for a, b, c, t, m in rows]


def portable_rows(f: dict) -> list[tuple]:
    p = f["portable"]
    return [("portable start: the fill's vehicles after its first step", "–",
             f"{p['n']} (state {p['state_n']})", "= state's", _met(p["n"] == p["state_n"])),
            (f"fill.json's vehicles within {NEAR:g} m of their pose", "–",
             f"portable {_f(p['near'], '{:.1f} %')} (state {_f(f['near'], '{:.1f} %')})", "≥ 99 %",
             _met(None if _nan(p["near"]) else p["near"] >= 99.0)),
            (f"portable start: collision / teleport events in the first {ROLLOUT:g} s", "–",
             f"{p['collisions']} / {p['teleports']} (state {f['collision_events']} / {f['teleport_events']})",
             "–", "–")]


def density_table(r: dict, o) -> list[str]:
    f, doc = r["fill"], r["doc"]
    km = doc["summary"]["car_lane_km"]
    d0, d1 = f["at"]["n"] / km, f["hold"]["n"] / km
    ok0, rel0 = _within(d0, o.density, 10)
    ok1, rel1 = _within(d1, o.density, 15)
    inflow = doc["inflow"]
    rows = [("density at start (veh/km of car lane)", f"{o.density:g}",
             f"{d0:.1f} ({rel0}; {f['at']['n']} vehicles on {km:.1f} km)", "±10 %", _met(ok0)),
            (f"density after {o.hold:g} s with the inflow", f"{o.density:g}",
             f"{d1:.1f} ({rel1}; {f['hold']['n']} vehicles)", "±15 %", _met(ok1)),
            (f"waiting to enter at {o.hold:g} s", "–", f"{f['hold']['waiting']}", "–", "–"),
            ("inflow", "–", f"period {inflow.get('period_s', '–')} s, trip {inflow.get('trip_s', '–')} s, "
             f"from {inflow.get('from', inflow.get('reason', '–'))}", "–", "–"),
            (f"collisions / teleports per 100 in the first {ROLLOUT:g} s", "–",
             f"{_f(f['collisions'])} / {_f(f['teleports'])} ({f['collision_events']} / {f['teleport_events']})",
             "–", "–")] + portable_rows(f) + [
            ("boxes overlapping at start (pairs)", "–", f"state {f['overlaps']}, portable "
             f"{f['portable']['overlaps']}", "–", "–"),
            ("wall time (s)", "–", f"fill {r['fill_wall']:.1f} ({r['fill_wall'] / max(km, 1e-9):.1f} s/km)", "–", "–")]
    head = [f"### {r['net']}: `{r['inputs']}`, no demand", "",
            f"Fill: `{r['command']}`", "", "| metric | requested | fill | target | met |", "|---|---|---|---|---|"]
    return head + [f"| {a} | {b} | {c} | {t} | {m} |" for a, b, c, t, m in rows]


def cost_table(results: list[dict]) -> list[str]:
    lines = ["### Cost", "", "| network | car-lane km | tiles | SUMO's warm-up (s) | fill, whole CLI (s) | "
             "fill s / km | fill.json timing_s |", "|---|---|---|---|---|---|---|"]
    for r in [x for res in results for x in (res, res.get("estimate")) if x]:
        if "doc" not in r or "error" in r:
            continue
        s = r["doc"]["summary"]
        warm = f"{r['sumo']['wall']:.2f}" if r["demand"] else "–"
        timing = ", ".join(f"{k} {v:g}" for k, v in r["doc"]["timing_s"].items())
        name = r["net"] + (" (estimate)" if "--demand-estimate" in r["command"] else "")
        lines.append(f"| {name} | {s['car_lane_km']:.1f} | {s['tiles']} | {warm} | {r['fill_wall']:.1f} | "
                     f"{r['fill_wall'] / max(s['car_lane_km'], 1e-9):.2f} | {timing} |")
    return lines


def tables(results: list[dict], o, command: str) -> str:
    lines = [f"Command: `{command}`", "", f"seed {o.seed}, warm-up {o.warmup:g} s, hold {o.hold:g} s, "
             f"step {o.step_length:g} s; counts are vehicles on the network (not those waiting to enter); "
             f"per-edge counts on normal edges; collisions / teleports per 100 vehicles present at the start "
             f"(events in brackets)", ""]
    for r in results:
        if "error" in r:
            lines += [f"### {r['net']}: the fill failed", "", r["error"]]
        else:
            lines += demand_table(r, o) if r["demand"] else density_table(r, o)
            if "estimate" in r:
                lines += ["", "The same from the demand estimate (`--demand-estimate`):", ""]
                lines += [r["estimate"]["error"]] if "error" in r["estimate"] else demand_table(r["estimate"], o)[2:]
        lines.append("")
    return "\n".join(lines + cost_table(results))
