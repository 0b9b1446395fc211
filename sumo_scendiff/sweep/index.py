"""The sweep's index (``index.csv``, ``index.jsonl``) and pictures (contact sheet, statistics plot),
rebuilt from the scenario folders on disk — so a resumed sweep's index is exactly an uninterrupted
one's: one row per planned scenario, in plan order.
"""
from __future__ import annotations

import csv
import json
import os

import numpy as np

from .spec import Scenario
from .worker import failure_path

COLUMNS = ("id", "status", "network", "location", "kind", "token_set", "p_mask", "p_mask_used", "seed",
           "steps", "threshold", "guidance", "scene_guidance", "pin_tokens", "pin_speeds", "lane_headings",
           "lane_snap", "rollout", "step_length", "replay", "user_tokens",
           "user_tokens_matched",
           "generated", "placed", "refused", "misplaced", "existing_vehicles", "dropped_on_existing",
           "collisions", "teleports", "emergency_brakes", "collisions_per_100", "teleports_per_100",
           "emergency_brakes_per_100", "mean_speed", "present_at_end", "arrived", "error")


def row_for(out: str, s: Scenario) -> dict:
    folder = os.path.join(out, s.id)
    if os.path.isdir(folder):
        with open(os.path.join(folder, "scene.json")) as f:
            sweep = json.load(f)["sweep"]
        with open(os.path.join(folder, "rollout.json")) as f:
            stats = json.load(f)
        row = {**s.params(), "status": "ok", "kind": sweep["kind"], "p_mask_used": sweep["p_mask_used"],
               **stats}
    elif os.path.exists(failure_path(out, s.id)):
        with open(failure_path(out, s.id)) as f:
            row = json.load(f)
    else:
        row = {**s.params(), "status": "missing"}
    return {c: row.get(c) for c in COLUMNS}


def write_index(out: str, scenarios: list[Scenario]) -> list[dict]:
    rows = [row_for(out, s) for s in scenarios]
    tmp = os.path.join(out, "index.jsonl.partial")
    with open(tmp, "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
    os.replace(tmp, os.path.join(out, "index.jsonl"))
    tmp = os.path.join(out, "index.csv.partial")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, os.path.join(out, "index.csv"))
    return rows


def contact_sheet(out: str, rows: list[dict], tile: int = 240, limit: int = 200) -> str | None:
    """One tile per scenario (its scene.png), labelled with the swept parameters."""
    import cv2

    from ..map.picture import contact_sheet as sheet
    tiles = []
    for r in [r for r in rows if r["status"] == "ok"][:limit]:
        img = cv2.imread(os.path.join(out, r["id"], "scene.png"))
        img = cv2.resize(img, (tile, tile), interpolation=cv2.INTER_AREA)
        band = np.full((34, tile, 3), 255, np.uint8)
        pm = r["p_mask_used"]
        lines = (f"{r['id']} {r['network']} {r['kind']}",
                 f"{r['token_set']} p_mask {pm:.2f} seed {r['seed']} agents {r['generated']}")
        for k, text in enumerate(lines):
            cv2.putText(band, text[:40], (3, 13 + 15 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (0, 0, 0), 1,
                        cv2.LINE_AA)
        tiles.append(np.vstack([band, img]))
    if not tiles:
        return None
    ncol = min(8, int(np.ceil(np.sqrt(len(tiles)))))
    grid = [tiles[i:i + ncol] for i in range(0, len(tiles), ncol)]
    path = os.path.join(out, "contact_sheet.png")
    cv2.imwrite(path, sheet(grid))
    return path


def stats_plot(out: str, rows: list[dict]) -> str | None:
    """Rollout statistics against the swept global token p_mask, one line per token set
    (mean over locations and seeds, bars: standard error)."""
    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return None
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = (("generated", "agents generated"), ("user_tokens_matched", "user tokens realised"),
              ("collisions_per_100", "collisions / 100 agents"), ("teleports_per_100", "teleports / 100 agents"),
              ("emergency_brakes_per_100", "emergency brakes (10 s) / 100"), ("mean_speed", "mean speed (m/s)"))
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5))
    for ax, (col, label) in zip(axes.ravel(), panels):
        for ts in sorted({r["token_set"] for r in ok}):
            sub = [r for r in ok if r["token_set"] == ts]
            xs = sorted({r["p_mask_used"] for r in sub})
            vals = [[r[col] for r in sub if r["p_mask_used"] == x] for x in xs]
            mean = [float(np.mean(v)) for v in vals]
            err = [float(np.std(v) / np.sqrt(len(v))) for v in vals]
            ax.errorbar(xs, mean, yerr=err, marker="o", capsize=3, label=ts)
        ax.set_xlabel("global scene token p_mask")
        ax.set_title(label, fontsize=10)
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    path = os.path.join(out, "stats.png")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
