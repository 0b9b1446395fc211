"""The seeding benchmark's tables (benchmarks/seeding.py): placement, rollout rates beside SUMO's own
traffic and Lane-uniform, and the collision events split by where and with whom."""
from __future__ import annotations

from collections import Counter

METHODS = ("SUMO", "Scenario Diffusion", "Lane-uniform")
RATES = (("collisions", "collisions / 100"), ("teleports", "teleports / 100"),
         ("emergency_brakes", "e-brake agents (first 10 s) / 100"))


def totals(stats: list) -> dict:
    agents = sum(s.agents for s in stats)
    d = {"agents": agents}
    for key, _ in RATES:
        d[key] = 100.0 * sum(getattr(s, key) for s in stats) / agents if agents else float("nan")
    # mean speed over agent-steps is what rollout reports per window; windows weighted by agents
    d["mean_speed"] = (sum(s.mean_speed * s.agents for s in stats) / agents) if agents else float("nan")
    return d


def _f(v, fmt="{:.2f}") -> str:
    return "–" if v != v else fmt.format(v)


def _ratio(a: float, b: float) -> str:
    if a != a or b != b:
        return "–"
    if b == 0:
        return "–" if a == 0 else "∞"
    return f"{a / b:.2f}"


def _merge(results: list[dict], method: str) -> dict:
    out = {"stats": [], "generated": 0, "dropped": 0, "refused": Counter(), "absent": 0, "off_pose": 0,
           "placed": 0, "slowed": 0, "fitted": 0, "junction": 0, "narrowed": 0, "pulled_back": 0, "to_stop_line": 0}
    for r in results:
        m = r["methods"][method]
        out["stats"] += m["stats"]
        out["refused"].update(m["refused"])
        for k in ("generated", "dropped", "absent", "off_pose", "placed", "slowed", "fitted", "junction",
                  "narrowed", "pulled_back", "to_stop_line"):
            out[k] += m.get(k, 0)
    return out


def _header(results: list[dict], o, command: str) -> list[str]:
    """The command, the settings and one row per net: its demand, windows, vehicles and wall times."""
    lines = [f"Command: `{command}`", "",
             f"seed {o.seed}, {o.windows} windows per net (auto_windows), warm-up {o.warmup:g} s, "
             f"rollout {o.rollout:g} s, step {o.step_length:g} s, sublane 0.8 m; the model's scenes at density "
             f"{getattr(o, 'scene_density', 'model')}"
             f"{', lights given' if getattr(o, 'signals', False) else ''}; a fresh SUMO at the state T "
             f"per rollout, in one worker process per net, address space randomisation off: "
             f"{'yes' if all(r.get('repeatable') for r in results) else 'NO (numbers may vary)'}", "",
             "| network | demand | windows (kinds) | vehicles on the net at T | wall (s): warm-up / generate / "
             "windows / total |", "|---|---|---|---|---|"]
    for r in results:
        s = r["seconds"]
        kinds = ", ".join(f"{v} {k}" for k, v in r["kinds"].items())
        lines.append(f"| {r['net']} | {r['demand']} | {r['windows']} ({kinds}) | {r['on_road']} | "
                     f"{s['warmup']:.1f} / {s['generate']:.1f} / {s['windows']:.1f} / {s['total']:.1f} |")
    return lines


def _placement(results: list[dict], groups: list) -> list[str]:
    """Per net and method, where the generated agents stood after the first step; the refusals' reasons."""
    lines = ["", "### Placement: generated agents within 0.5 m / 0.1 rad of their pose after the first step",
             "", "| network | method | generated | dropped (on existing) | dropped (junction foe) | refused "
             "| absent after step | off pose | placed | placement (placed / generated) "
             "| placement of those seeded (placed / generated − dropped) | slowed to a safe speed "
             "| minGap fitted to SUMO's leader | narrowed to the junctions' width | nose moved back behind "
             "the stop line | moved from a red junction to its stop line |", "|---|" + "---|" * 15]
    for label, methods in groups:
        for k, name in enumerate(METHODS[1:]):
            m = methods[name]
            rate = 100.0 * m["placed"] / m["generated"] if m["generated"] else float("nan")
            meant = m["generated"] - m["dropped"] - m.get("junction", 0)
            rate2 = 100.0 * m["placed"] / meant if meant else float("nan")
            lines.append(f"| {label if k == 0 else ''} | {name} | {m['generated']} | {m['dropped']} | "
                         f"{m.get('junction', 0)} | {sum(m['refused'].values())} | {m['absent']} | "
                         f"{m['off_pose']} | {m['placed']} | {_f(rate, '{:.1f} %')} | {_f(rate2, '{:.1f} %')} | "
                         f"{m['slowed']} | {m['fitted']} | {m.get('narrowed', 0)} | {m.get('pulled_back', 0)} | "
                         f"{m.get('to_stop_line', 0)} |")
    for name in METHODS[1:]:
        refused = Counter()
        for r in results:
            refused.update(r["methods"][name]["refused"])
        lines += ["", f"Refusal reasons, {name}: " + ("none" if not refused else "")]
        if refused:
            lines += ["", "| count | reason |", "|---|---|"]
            lines += [f"| {n} | {reason} |" for reason, n in refused.most_common()]
    return lines


def _rollout(groups: list, o) -> list[str]:
    """Per net and method, the rollout's rates per 100 agents and their ratio to SUMO's own traffic."""
    head = " | ".join(c for _, c in RATES)
    lines = ["", f"### Rollout: {o.rollout:g} s after hand-off, same windows and state; "
                 "rates per 100 agents, ratio to SUMO's own traffic", "",
             f"| network | method | agents | {head} | mean speed (m/s) | collisions × SUMO | "
             "teleports × SUMO | e-brakes × SUMO | speed × SUMO |", "|---|" * 1 + "---|" * 10]
    for label, methods in groups:
        ref = totals(methods["SUMO"]["stats"])
        for k, name in enumerate(METHODS):
            d = totals(methods[name]["stats"])
            cells = [str(d["agents"])] + [_f(d[key]) for key, _ in RATES] + [_f(d["mean_speed"])]
            ratios = ["" if name == "SUMO" else _ratio(d[key], ref[key]) for key, _ in RATES]
            ratios.append("" if name == "SUMO" else _ratio(d["mean_speed"], ref["mean_speed"]))
            lines.append(f"| {label if k == 0 else ''} | {name} | " + " | ".join(cells + ratios) + " |")
    return lines


def _collisions(groups: list) -> list[str]:
    """The collision events by where and with whom, the teleports; the whole simulation's collision rate."""
    from sumo_scendiff.sim.rollout import RolloutStats
    kinds = (("collisions_junction", "on a junction"), ("collisions_host", "with a host vehicle"),
             ("collisions_host_behind", "a host vehicle ran into the agent"),
             ("collisions_early", f"in the first {RolloutStats().brake_window:g} s"))
    lines = ["", "Collision events (an event can be in several columns) and teleports, per net and in all:", "",
             "| network | method | collisions | " + " | ".join(c for _, c in kinds) + " | teleports |",
             "|---|---|" + "---|" * (2 + len(kinds))]
    for label, methods in groups:
        for k, name in enumerate(METHODS):
            stats = methods[name]["stats"]
            lines.append(f"| {label if k == 0 else ''} | {name} | {sum(s.collisions for s in stats)} | "
                         + " | ".join(str(sum(getattr(s, key) for s in stats)) for key, _ in kinds)
                         + f" | {sum(s.teleports for s in stats)} |")
    lines += ["", "The whole simulation, every vehicle (the host's own collisions too; the SUMO runs of one net all "
              "drive the same state, so their mean is one 60-s sample of it): collisions per 100 vehicles "
              "present during a rollout, mean over its runs:", "",
              "| network | " + " | ".join(METHODS) + " |", "|---|" + "---|" * len(METHODS)]
    for label, methods in groups:
        cells = []
        for name in METHODS:
            runs = [s for s in methods[name]["stats"] if getattr(s, "network_vehicles", 0)]
            rate = (sum(100.0 * s.network_collisions / s.network_vehicles for s in runs) / len(runs)) if runs else float("nan")
            cells.append(_f(rate))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def tables(results: list[dict], o, command: str) -> str:
    groups = [(r["net"], r["methods"]) for r in results]
    if len(results) > 1:
        groups.append((f"**all ({len(results)} nets)**", {m: _merge(results, m) for m in METHODS}))
    return "\n".join(_header(results, o, command) + _placement(results, groups) + _rollout(groups, o)
                     + _collisions(groups))
