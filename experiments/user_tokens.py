"""Partial tokens as a user writes them: is what the token gives what the scene gets?

    python experiments/user_tokens.py [--cities resco_cologne3 ...] [--windows 10] [-o FILE]

Per real city in /work/shared/nets (default: every folder whose network has its own demand,
``data.demand.find_demand``), SUMO's own traffic on its own demand (.rou.xml) is recorded by
the evaluation cache (``evaluate.__main__.record_cached``, the same recordings ``evaluate`` uses). In
each recorded window one to three of SUMO's vehicles become partial tokens of one kind at a time:

* ``x,y,speed``; ``x,y,heading,speed``: the vehicle's own values;
* ``stop``: x, y, heading, speed of a vehicle moving at >= 4 m/s, with ``final_speed`` 0 (asked to stop);
* ``turn``: x, y, heading, speed, heading_to_final of a vehicle turning (|heading_to_final| >= 0.1 rad).

The scene is generated at p_mask 0.5 (``--density``: and the window's recorded density, the level a
user asks with ``--density auto``) with delivery on (the default: generation/deliver.py) and off
(the model's own drawing, ``deliver_tokens=False``), and the generated agents are matched one-to-one to
the tokens (Hungarian on position within 2.2 m, heading within 0.2 rad where the token gives one).
Reported: match rate, |speed - asked| at t = 0, |speed at +2 s - asked final speed|, for turn
tokens the share whose generated +2 s direction turns the same way within 0.2 rad of the token's,
the vehicles per window beside SUMO's in the same windows (the traffic left to the model);
and how many tokens the delivered scenes name in a warning (``meta["token_warnings"]``: a token
that could not be placed, or a turn no lane makes). The stop tokens' speed error is also given
apart for those asked to stop from at most 9 m/s (a car's 4.5 m/s^2 stands it within the 2 s the
trajectory runs) and from faster (a harder stop than SUMO's default decel); and the drawn speed's
mean signed error by the asked speed's band, every kind together (where the map's limits pull).
"""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

import numpy as np
from report import emit

from sumo_scendiff.core.threads import share_cpu

share_cpu(default=1)   # before torch is imported: one thread, the machine is shared

from sumo_scendiff.core.geometry import T0, wrap_angle
from sumo_scendiff.core.matching import match_agents
from sumo_scendiff.data.demand import find_demand
from sumo_scendiff.data.shards import SceneStore
from sumo_scendiff.evaluate.__main__ import SHARED_NETS, record_cached
from sumo_scendiff.generation.generator import ScenarioGenerator
from sumo_scendiff.map.network import Network
from sumo_scendiff.tokens.encoding import feature_dicts, features_from_scene

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
KINDS = {"x,y,speed": ("x", "y", "speed"),
         "x,y,heading,speed": ("x", "y", "heading", "speed"),
         "stop (speed >= 4, final 0)": ("x", "y", "heading", "speed"),
         "turn (heading_to_final)": ("x", "y", "heading", "speed", "heading_to_final")}
TURN_MIN, TURN_AGREE = 0.1, 0.2     # rad
# m/s: a stop token from faster than this asks for more than a car's 4.5 m/s^2 (SUMO's default decel)
# to stand within the 2 s the trajectory runs; its speed error is reported apart too
GENTLE_STOP = 9.0


def tokens_of(scene, kind: str, rng: np.random.Generator) -> list[dict]:
    """One to three of the window's vehicles as tokens of ``kind``."""
    feats, present = features_from_scene(scene.boxes, scene.traj, scene.traj_mask, scene.speed)
    every = feature_dicts(feats, present)
    names = KINDS[kind]
    ok = [i for i, d in enumerate(every) if all(f in d for f in names)]
    if kind.startswith("stop"):
        ok = [i for i in ok if every[i]["speed"] >= 4.0]
    if kind.startswith("turn"):
        ok = [i for i in ok if abs(every[i]["heading_to_final"]) >= TURN_MIN]
    if not ok:
        return []
    pick = rng.choice(ok, size=min(len(ok), int(rng.integers(1, 4))), replace=False)
    toks = [{f: every[i][f] for f in names} for i in sorted(pick)]
    if kind.startswith("stop"):
        toks = [dict(t, final_speed=0.0) for t in toks]
    return toks


def heading_to_final(traj: np.ndarray) -> float:
    d = traj[-1, :2] - traj[T0, :2]
    return float(wrap_angle(np.arctan2(d[1], d[0]) - traj[T0, 2]))


def score(scenes, tokens, recorded: list[int]) -> dict:
    """Match, speed errors and turns of ``scenes`` against their ``tokens``; ``recorded``: the
    vehicles in each window as SUMO had them (the scenes' counts are compared with them)."""
    n = matched = 0
    warned = sum(len({line.split(" at ")[0] for line in s.meta.get("token_warnings", ())}) for s in scenes)
    speed, final, turn, signed, signed_final, asked = [], [], [], [], [], []
    for s, toks in zip(scenes, tokens):
        n += len(toks)
        tb = np.array([[t["x"], t["y"], t.get("heading", np.nan)] for t in toks]).reshape(-1, 3)
        gi, ti = match_agents(s.boxes[:, :3], tb)
        matched += len(gi)
        for g, k in zip(gi, ti):
            t = toks[k]
            signed.append(float(s.speed[g, T0]) - t["speed"])
            speed.append(abs(signed[-1]))
            asked.append(t["speed"])
            if "final_speed" in t:
                signed_final.append(float(s.speed[g, -1]) - t["final_speed"])
                final.append(abs(signed_final[-1]))
            if "heading_to_final" in t:
                h = heading_to_final(s.traj[g].astype(np.float64))
                turn.append(np.sign(h) == np.sign(t["heading_to_final"])
                            and abs(h - t["heading_to_final"]) <= TURN_AGREE)
    return summary({"n": n, "matched": matched, "speed": speed, "final": final, "turn": turn, "warned": warned,
                    "signed": signed, "signed_final": signed_final, "asked": asked, "windows": len(scenes),
                    "vehicles": sum(len(s.boxes) for s in scenes), "recorded": sum(recorded)})


def summary(raw: dict) -> dict:
    """The table's figures of :func:`score`'s raw counts and errors (``raw`` kept, to pool cities)."""
    mean = (lambda v: float(np.mean(v)) if v else float("nan"))
    return {"tokens": raw["n"], "match": raw["matched"] / max(raw["n"], 1), "speed": mean(raw["speed"]),
            "final": mean(raw["final"]), "turn": mean(raw["turn"]), "warned": raw["warned"], "raw": raw,
            "bias": mean(raw["signed"]), "final_bias": mean(raw["signed_final"]),
            "per_window": raw["vehicles"] / max(raw["windows"], 1), "recorded": raw["recorded"] / max(raw["windows"], 1)}


def gentle(raw: dict, label: str) -> str:
    """The stop tokens' speed MAE split at :data:`GENTLE_STOP` (a stop a car's decel allows, or not)."""
    err, asked = np.array(raw["speed"]), np.array(raw["asked"])
    part = (lambda k: f"{err[k].mean():.2f} m/s over {int(k.sum())}" if k.any() else "–")
    return (f"Stop tokens ({label}): speed MAE from ≤ {GENTLE_STOP:g} m/s {part(asked <= GENTLE_STOP)}, "
            f"from faster (more than 4.5 m/s² to stand in 2 s) {part(asked > GENTLE_STOP)}.  ")


BANDS = (0.0, 4.0, 9.0, 12.0, np.inf)   # m/s: standing and slow, a city street's, near its limit, beyond


def by_speed(raw: dict, label: str) -> str:
    """The mean signed speed error (drawn - asked) by the asked speed's band: where the model's own
    speed prior (the map's limits) pulls a token's vehicle, and which way."""
    err, asked = np.array(raw["signed"]), np.array(raw["asked"])
    parts = [f"[{lo:g}, {hi:g}) {err[k].mean():+.2f} over {int(k.sum())}"
             for lo, hi in zip(BANDS[:-1], BANDS[1:]) for k in [(asked >= lo) & (asked < hi)] if k.any()]
    return f"Speed error by the asked speed ({label}), m/s: " + ", ".join(parts) + ".  "


def pooled(results: list[dict]) -> dict:
    """One :func:`summary` of several cities' results."""
    lists = ("speed", "final", "turn", "signed", "signed_final", "asked")
    raw = {k: sum((r["raw"][k] for r in results), [] if k in lists else 0)
           for k in ("n", "matched", "warned", "windows", "vehicles", "recorded") + lists}
    return summary(raw)


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cities", nargs="+", default=None,
                   help="folders of /work/shared/nets holding a network and its .rou.xml (default: "
                        "every one whose network has demand)")
    p.add_argument("-n", "--net-file", dest="nets", action="append", default=None, metavar="NET",
                   help="a network instead of the cities (repeat): its own demand beside it, else random "
                        "trips -- the held-out generated networks, to choose a setting on")
    p.add_argument("--windows", type=int, default=10, help="recorded windows per city")
    p.add_argument("--p-mask", type=float, default=0.5)
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("--cache", default=os.path.join(ROOT, ".cache", "eval"))
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--guidance", type=float, default=None, help="token guidance weight (default: generate's)")
    p.add_argument("--plain-guidance", dest="local_guidance", action="store_false", default=None,
                   help="the tokens' guidance over the whole window, the paper's (default: local and projected)")
    p.add_argument("--steps", type=int, default=None, help="ODE steps (default: generate's)")
    p.add_argument("--sampler", default=None, help="ODE solver (default: generate's)")
    p.add_argument("--binned-token-values", dest="exact_token_values", action="store_false", default=None,
                   help="the decoder reads the tokens' speeds and turn as their bins' centres (generate's flag)")
    p.add_argument("--drawn-only", action="store_true", help="only the model's own drawing (no delivery)")
    p.add_argument("--density", action="store_true",
                   help="each window also given its recorded density (the density token: SUMO's own level "
                        "there, kept as a count around the tokens' vehicles)")
    p.add_argument("-o", "--output", default=None, help="also write the table here (markdown)")
    return p.parse_args(args)


def network_of(city: str) -> Network:
    folder = os.path.join(SHARED_NETS, city)
    nets = [f for f in sorted(os.listdir(folder)) if f.endswith((".net.xml", ".net.xml.gz"))]
    if not nets:
        sys.exit(f"user_tokens.py: {folder}: no .net.xml")
    return Network.load(os.path.join(folder, nets[0]))


def cities_with_demand() -> list[str]:
    """The folders of /work/shared/nets whose network has a demand file of its own."""
    out = []
    for city in sorted(os.listdir(SHARED_NETS)):
        folder = os.path.join(SHARED_NETS, city)
        if os.path.isdir(folder) and any(f.endswith(".rou.xml") for f in os.listdir(folder)) \
                and find_demand(network_of(city)) is not None:
            out.append(city)
    return out


def row(city: str, kind: str, res: list[dict]) -> str:
    fmt = (lambda k, p: "–" if all(np.isnan(r[k]) for r in res) else " / ".join(f"{r[k]:.{p}f}" for r in res))
    return (f"| {city} | {kind} | {res[0]['tokens']} | {fmt('match', 2)} | {fmt('speed', 2)} | "
            f"{fmt('final', 2)} | {fmt('turn', 2)} | {fmt('per_window', 1)} ({res[0]['recorded']:.1f}) | "
            f"{res[0]['warned'] if len(res) > 1 else '–'} |")


def main(o) -> int:
    gen = ScenarioGenerator.load(o.checkpoint)
    base = replace(gen.config, **{k: getattr(o, k) for k in ("guidance", "local_guidance", "steps", "sampler", "exact_token_values")
                                  if getattr(o, k) is not None}).validate()
    modes = (False,) if o.drawn_only else (True, False)
    every: dict[str, list[list[dict]]] = {}
    cities, stops = [], []
    lines = [("| city | tokens | n | match (delivered / drawn) | speed MAE m/s | final speed MAE m/s | turn agreement "
              "| vehicles per window (SUMO's) | warned |"), "|---|---|---|---|---|---|---|---|---|"]
    for city in o.nets or o.cities or cities_with_demand():
        net = Network.load(city) if o.nets else network_of(city)
        store = SceneStore(record_cached([net.path], [find_demand(net)], o.windows, o.seed, o.cache,
                                         f"gt-{net.name}"))
        gts = [store.scene(i) for i in range(min(o.windows, len(store)))]
        for kind in KINDS:
            rng = np.random.default_rng([o.seed, list(KINDS).index(kind)])
            pairs = [(g, t) for g in gts for t in [tokens_of(g, kind, rng)] if t]
            if not pairs:
                continue
            windows, toks = [g.window for g, _ in pairs], [t for _, t in pairs]
            lights = [g.meta.get("signals") or None for g, _ in pairs]   # the recorded moment's lights
            dens = [len(g.boxes) / max(net.car_lane_km(g.window), 1e-3) for g, _ in pairs] if o.density else None
            res = [score(gen.generate(net, windows, tokens=toks, p_mask=o.p_mask, seed=o.seed, signals=lights,
                                      density=dens, config=replace(base, deliver_tokens=d)), toks,
                         [len(g.boxes) for g, _ in pairs]) for d in modes]
            every.setdefault(kind, []).append(res)
            cities.append((res, kind, net.name))
            lines.append(row(net.name, kind, res))
            print(lines[-1], file=sys.stderr)
    for kind, res in every.items():      # every city's tokens together
        res = [pooled([r[m] for r in res]) for m in range(len(modes))]
        lines.append(row("**all**", kind, res))
        bias = (lambda k, res=res: " / ".join(f"{r[k]:+.2f}" for r in res))
        print(f"{kind}: mean signed error of the speed {bias('bias')}, of the final speed {bias('final_bias')} m/s",
              file=sys.stderr)
        if kind.startswith("stop"):
            stops = [gentle(r["raw"], m) for m, r in zip(("delivered", "drawn")[-len(modes):], res)]
    stops += [gentle(r[-1]["raw"], f"drawn, {name}") for r, kind, name in cities if kind.startswith("stop")]
    lines += [""] + stops if stops else []
    drawn = pooled([r[-1] for res in every.values() for r in res])     # every kind, the model's own
    lines += ["", by_speed(drawn["raw"], "drawn, every kind and city")]
    emit("\n".join(lines) + "\n", o.output, "Partial tokens as a user writes them")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
