"""An exported scene as the file says it, next to its scene.png (the figure of docs/openscenario.md).

    python -m sumo_scendiff.export.picture out/scene_000 docs/openscenario-scene.png

Right: the OpenDRIVE's roads (each road's reference line, read from ``scenario.xodr``'s planView) and
the ``scenario.xosc`` read back: the Init boxes (the token reader's, tokens/xosc.py) and each story's
polyline, the ``generated`` one dashed. Left: the folder's own scene.png.
"""
from __future__ import annotations

import math
import os
import sys
import xml.etree.ElementTree as ET

import numpy as np


def _road_lines(xodr: str, box: tuple[float, float, float, float]) -> list[np.ndarray]:
    """Reference lines of the roads inside ``box`` (x0, y0, x1, y1): lines exactly, other
    geometries (arcs, parametric cubics) as the chord of their start and end headings."""
    out = []
    for g in ET.parse(xodr).getroot().iter("geometry"):
        x, y, h, s = (float(g.get(k)) for k in ("x", "y", "hdg", "length"))
        if not (box[0] - s <= x <= box[2] + s and box[1] - s <= y <= box[3] + s):
            continue
        out.append(np.array([[x, y], [x + s * math.cos(h), y + s * math.sin(h)]]))
    return out


def _polylines(root: ET.Element) -> list[tuple[str, np.ndarray]]:
    out = []
    for story in root.iter("Story"):
        for line in story.iter("Polyline"):
            xy = [(float(v.find("Position/WorldPosition").get("x")), float(v.find("Position/WorldPosition").get("y")))
                  for v in line.findall("Vertex")]
            out.append((story.get("name"), np.array(xy)))
    return out


def draw(folder: str, out: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    from ..core.geometry import box_corners
    from ..tokens.xosc import xosc_tokens
    xosc = os.path.join(folder, "scenario.xosc")
    agents = xosc_tokens(xosc)["agents"]
    xy = np.array([[a["x"], a["y"]] for a in agents])
    lo, hi = xy.min(0) - 30.0, xy.max(0) + 30.0
    fig, (left, right) = plt.subplots(1, 2, figsize=(14, 7))
    left.imshow(plt.imread(os.path.join(folder, "scene.png")))
    left.set_title("scene.png (SUMO)")
    left.axis("off")
    for line in _road_lines(os.path.join(folder, "scenario.xodr"), (*lo, *hi)):
        right.plot(line[:, 0], line[:, 1], color="0.6", lw=1)
    for story, line in _polylines(ET.parse(xosc).getroot()):
        right.plot(line[:, 0], line[:, 1], "--" if story == "generated" else "-",
                   color="tab:blue" if story == "generated" else "tab:orange",
                   lw=2.0 if story == "generated" else 1.0, zorder=3 if story == "generated" else 2)
    for a in agents:
        corners = box_corners(a["x"], a["y"], a["heading"], a["length"], a["width"])
        right.add_patch(Polygon(corners, closed=True, fill=False, color="k", lw=1))
    right.set_xlim(lo[0], hi[0])
    right.set_ylim(lo[1], hi[1])
    right.set_aspect("equal")
    right.set_title("scenario.xosc on scenario.xodr: Init boxes, sumo story (solid), generated (dashed)")
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def get_options(args=None):
    import argparse
    ap = argparse.ArgumentParser(prog="python -m sumo_scendiff.export.picture",
                                 description="an exported scene folder drawn from its scenario.xosc and "
                                             "scenario.xodr, beside its scene.png")
    ap.add_argument("folder", help="a scene folder exported as OpenSCENARIO (python -m sumo_scendiff.export)")
    ap.add_argument("output", help="the PNG to write")
    o = ap.parse_args(args)
    o.parser = ap
    missing = [f for f in ("scene.png", "scenario.xosc", "scenario.xodr") if not os.path.isfile(os.path.join(o.folder, f))]
    if missing:
        ap.exit(2, f"{ap.prog}: error: {o.folder}: no {', '.join(missing)} (export the folder first: "
                   f"python -m sumo_scendiff.export {o.folder})\n")
    if os.path.exists(o.output) and not o.output.lower().endswith(".png"):
        ap.exit(2, f"{ap.prog}: error: {o.output}: exists and is not a PNG; not overwritten\n")
    return o


def main(o) -> int:
    try:
        draw(o.folder, o.output)
    except (OSError, ValueError, ET.ParseError) as e:
        o.parser.exit(2, f"{o.parser.prog}: error: {e}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
