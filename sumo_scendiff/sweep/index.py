"""The sweep's index (``index.csv``, ``index.jsonl``) and pictures (contact sheet, statistics plot),
rebuilt from the scenario folders on disk — so a resumed sweep's index is exactly an uninterrupted
one's: one row per planned scenario, in plan order.
"""
from __future__ import annotations

import csv
import json
import os

import numpy as np

from ..core.scene import per_km
from .spec import Scenario
from .worker import failure_path

COLUMNS = ("id", "status", "network", "location", "kind", "token_set", "p_mask", "p_mask_used",
           "density", "vehicles", "density_target_veh_per_km", "seed",
           "steps", "threshold", "guidance", "scene_guidance", "pin_tokens", "pin_speeds", "lane_headings",
           "lane_snap", "rollout", "step_length", "replay", "user_tokens",
           "user_tokens_matched", "user_tokens_lost",
           "generated", "placed", "misplaced", "refused", "existing", "dropped", "existing_vehicles", "dropped_on_existing",
           "vehicles_in_window", "density_veh_per_km",
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
               "density_target_veh_per_km": sweep.get("density_target_veh_per_km"), **stats}
        if isinstance(stats.get("user_tokens_lost"), dict):   # the reasons are in the scene's own files
            row["user_tokens_lost"] = len(stats["user_tokens_lost"])
        if "existing_vehicles" in stats and "placed" in stats:   # as run's summary counts them
            row["vehicles_in_window"] = stats["existing_vehicles"] + stats["placed"]
            density = per_km(row["vehicles_in_window"], sweep.get("car_lane_km"))
            row["density_veh_per_km"] = None if density is None else round(density, 2)
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


def sheet_path(out: str, page: int) -> str:
    """Page 0 is ``contact_sheet.png``, page k > 0 ``contact_sheet-{k + 1}.png``."""
    return os.path.join(out, "contact_sheet.png" if page == 0 else f"contact_sheet-{page + 1}.png")


def contact_sheet(out: str, rows: list[dict], tile: int = 480, per_page: int = 24, ncol: int = 4) -> str | None:
    """One captioned tile per scenario (its scene.png), ``per_page`` to a sheet: contact_sheet.png,
    contact_sheet-2.png, ... Returns the first page's path."""
    import glob

    import cv2

    from ..core.files import write_png
    from ..map.picture import contact_sheets
    images, captions = [], []
    for r in [r for r in rows if r["status"] == "ok"]:
        images.append(cv2.imread(os.path.join(out, r["id"], "scene.png")))
        level = "" if r.get("density_target_veh_per_km") is None else \
            f"  {r['density_target_veh_per_km']:.0f} veh/km"
        captions.append((f"{r['id']}  {r['network']}  {r['kind']}",
                         (f"{r['token_set']}  p_mask {r['p_mask_used']:.2f}{level}  seed {r['seed']}  "
                          f"agents {r['generated']}")))
    for stale in glob.glob(os.path.join(out, "contact_sheet-*.png")):
        os.remove(stale)  # pages of an earlier build that this one may not rewrite
    if not images:
        return None
    ncol = min(ncol, int(np.ceil(np.sqrt(min(len(images), per_page)))))
    for k, sheet in enumerate(contact_sheets(images, captions, tile=tile, ncol=ncol, per_page=per_page)):
        tmp = sheet_path(out, k)[:-4] + ".partial.png"
        write_png(tmp, sheet)
        os.replace(tmp, sheet_path(out, k))
    return sheet_path(out, 0)


def _request(r: dict):
    """A row's traffic-level request: ("density", value or "auto"), ("vehicles", n) or None."""
    if r.get("vehicles") is not None:
        return ("vehicles", r["vehicles"])
    return None if r.get("density") is None else ("density", r["density"])


def density_axis(rows: list[dict]) -> bool:
    """Whether the statistics go against density: the sweep varies the traffic level (density or
    vehicles) and not the global token p_mask."""
    ok = [r for r in rows if r["status"] == "ok"]
    return len({_request(r) for r in ok}) > 1 and len({r["p_mask_used"] for r in ok}) <= 1 and \
        any(r.get("density_target_veh_per_km") is not None for r in ok)


def stats_plot(out: str, rows: list[dict]) -> str | None:
    """Rollout statistics against the swept global token p_mask, one line per token set
    (mean over locations and seeds, bars: standard error). A sweep that varies the traffic level
    (density or vehicles) rather than p_mask is plotted against the density target instead (each
    request at the mean of its targets; requests left to the model's prior are left out), its first
    panel the density reached beside the line where it equals the target."""
    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return None
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    by_density = density_axis(rows)
    if by_density:
        ok = [r for r in ok if r.get("density_target_veh_per_km") is not None]
        at = {}
        for req in {_request(r) for r in ok}:
            at[req] = float(np.mean([r["density_target_veh_per_km"] for r in ok if _request(r) == req]))
        xof = lambda r: at[_request(r)]
        xlabel = "density target (veh / km of car lane)"
        first = ("density_veh_per_km", "density reached (veh / km)")
    else:
        xof = lambda r: r["p_mask_used"]
        xlabel = "global scene token p_mask"
        first = ("generated", "agents generated")
    panels = (first, ("user_tokens_matched", "user tokens realised"),
              ("collisions_per_100", "collisions / 100 agents"), ("teleports_per_100", "teleports / 100 agents"),
              ("emergency_brakes_per_100", "emergency brakes (10 s) / 100"), ("mean_speed", "mean speed (m/s)"))
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5))
    for ax, (col, label) in zip(axes.ravel(), panels):
        for ts in sorted({r["token_set"] for r in ok}):
            sub = [r for r in ok if r["token_set"] == ts and r.get(col) is not None]
            xs = sorted({xof(r) for r in sub})
            vals = [[r[col] for r in sub if xof(r) == x] for x in xs]
            mean = [float(np.mean(v)) for v in vals]
            err = [float(np.std(v) / np.sqrt(len(v))) for v in vals]
            ax.errorbar(xs, mean, yerr=err, marker="o", capsize=3, label=ts)
        if by_density and col == "density_veh_per_km" and at:
            lim = [0.0, max(at.values())]
            ax.plot(lim, lim, "k--", lw=0.8, label="target")
        ax.set_xlabel(xlabel)
        ax.set_title(label, fontsize=10)
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    path = os.path.join(out, "stats.png")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
