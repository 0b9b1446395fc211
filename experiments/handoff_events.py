"""Print every collision / teleport / early hard braking of the seeding benchmark's --events pickle.

    python benchmarks/seeding.py --windows 8 --events ev.pkl; python experiments/handoff_events.py ev.pkl [method]
"""
import pickle
import sys
from collections import Counter


def short(p):
    if p is None:
        return "-"
    s = p.get("seed") or {}
    who = "AGENT" if p["agent"] else "host"
    out = (f"{who} {p['id']} lane={p.get('lane','?')} v={p.get('speed', float('nan')):.1f} wait={p.get('wait', 0):.0f}"
           f" L={p.get('length', 0):.1f} W={p.get('width', 0):.2f} lat={p.get('lat', 0):.2f} {p.get('vclass', '')}")
    if p.get("link"):
        L = p["link"]
        out += f" link[{L.get('state')} prio={L.get('prio')} dir={L.get('dir')} from={L.get('from')}]"
    if s:
        nl = s.get("next_link") or {}
        out += (f"\n        seeded: lane={s.get('lane')} internal={s.get('internal')} to_end={s.get('to_end', float('nan')):.1f} "
                f"v={s.get('speed', float('nan')):.1f} gen_v={s.get('gen_speed'):.1f} slowed={s.get('slowed')} "
                f"next_link[{nl.get('state')} prio={nl.get('prio')} open={nl.get('open')} foe={nl.get('foe')} dir={nl.get('dir')}]")
    h = p.get("hist") or []
    if h:
        out += "\n        hist: " + " ".join(f"{x[0]:g}:{x[1]}@{x[2]:.0f}/{x[3]:.1f}" + (f"/lat{x[4]:.1f}" if len(x) > 4 else "") for x in h[-8:])
    return out


def main(path, method="Scenario Diffusion"):
    ev = pickle.load(open(path, "rb"))
    c = Counter((e["method"], e["kind"]) for e in ev)
    print(c)
    for e in ev:
        if method and e["method"] != method:
            continue
        if e["kind"] in ("host-host", "seeded"):
            continue
        if e["kind"] == "brake":
            print(f"\n## BRAKE {e['method'][:4]} {e['net']} w{e['window']} t={e['t']:.1f} a={e['accel']:.1f} decel={e.get('decel')} "
                  f"gap={e.get('gap')} tls={e.get('tls')}")
            print("   who:   ", short(e["who"]))
            print("   leader:", short(e.get("leader")))
            continue
        if e["kind"] == "collision":
            print(f"\n== {e['method'][:4]} {e['net']} w{e['window']} t={e['t']:.1f} {e['type']} on {e['lane']} pos={e['pos']:.1f} "
                  f"speeds collider {e['collider_speed']:.1f} victim {e['victim_speed']:.1f}")
            print("   collider:", short(e["collider"]))
            print("   victim:  ", short(e["victim"]))
        else:
            print(f"-- teleport {e['net']} w{e['window']} t={e['t']:.1f} {e['who']['id']} lane={e['who'].get('lane')}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "Scenario Diffusion")
