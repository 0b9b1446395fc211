"""Classify the seeding benchmark's collision events (--events pickle) by movement, link right of way
and who hit whom.

    python experiments/handoff_classify.py ev_8.pkl [ev_16.pkl ...]
"""
import pickle
import sys
from collections import Counter, defaultdict


def junction(lane):
    return lane[1:].rsplit("_", 2)[0] if lane.startswith(":") else None


def classify(e):
    c, v = e["collider"], e["victim"]
    parties = [c, v]
    links = [(p.get("link") or {}) for p in parties]
    minor = [l.get("state") in ("g", "m", "s", "=") or l.get("dir") in ("t",) for l in links]
    standing = [(p.get("hist") or [(0, "", 0, 9)])[-1][3] < 0.5 for p in parties]
    t = e["t"]
    if t <= 10:
        return "early (<=10 s)"
    if any(m for m in minor) and any(not m for m in minor):
        i = minor.index(True)
        lt = links[i].get("dir")
        return f"{'turn ' + lt} on permissive link ({links[i].get('state')}) vs priority link; turner {'standing' if standing[i] else 'moving'}"
    return f"other: states {[l.get('state') for l in links]} dirs {[l.get('dir') for l in links]}"


def main(paths):
    for path in paths:
        ev = pickle.load(open(path, "rb"))
        hh = defaultdict(set)   # (net, window, method) -> host ids in host-host collisions
        hhj = defaultdict(set)
        for e in ev:
            if e["kind"] == "host-host":
                hh[(e["net"], e["window"], e["method"])].update(e["ids"])
                hhj[(e["net"], e["method"])].add(junction(e["lane"]))
        n_hh = Counter(e["method"] for e in ev if e["kind"] == "host-host")
        print(f"\n#### {path}: host-host collisions (not counted) per method {dict(n_hh)}")
        for m in ("SUMO", "Scenario Diffusion"):
            cls = Counter()
            for e in ev:
                if e["kind"] != "collision" or e["method"] != m:
                    continue
                k = classify(e)
                hosts = [p["id"] for p in (e["collider"], e["victim"]) if not p["agent"]]
                trap = any(h in hh[(e["net"], e["window"], "SUMO")] for h in hosts)
                trapj = junction(e["lane"]) in hhj[(e["net"], "SUMO")]
                seeded_internal = any((p.get("seed") or {}).get("internal") for p in (e["collider"], e["victim"]) if p["agent"])
                kind = ("agent-agent" if not hosts else "agent-host")
                cls[(k, kind, "host also collides in SUMO's run" if trap else
                     ("junction has host-host collisions in SUMO's runs" if trapj else "-"),
                     "an agent seeded on the junction" if seeded_internal else "")] += 1
            print(f"  {m}: {sum(cls.values())} collisions")
            for k, n in cls.most_common():
                print(f"    {n:3d}  {' | '.join(x for x in k if x)}")


if __name__ == "__main__":
    main(sys.argv[1:])
