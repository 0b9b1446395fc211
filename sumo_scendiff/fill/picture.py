"""fill.png: the whole network, each edge coloured by the density of the fill, the vehicles drawn."""
from __future__ import annotations

import numpy as np

from ..core.geometry import box_corners

BOXES_UP_TO_M = 1500.0   # m across: wider networks get a dot per vehicle (a box would be 1-2 px)


def edge_density(net, rows: np.ndarray) -> dict[str, float]:
    """Vehicles per km of lane per normal edge, each vehicle counted on the car lane under it."""
    counts: dict[str, int] = {}
    if len(rows):
        m = net.match_poses(rows[:, :2], rows[:, 2])
        for lane in m.lane[m.lane >= 0]:
            ln = net.lanes[lane]
            if not ln.internal:
                counts[ln.edge] = counts.get(ln.edge, 0) + 1
    return {e: counts.get(e, 0) / max(k, 1e-3) for e, k in net.edge_car_km.items()}


def frame(net) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) of the network's car lanes: what the picture shows (its rails and footpaths
    may reach far beyond them)."""
    if not len(net.car_lane_ids):
        return net.bounds
    xy = np.concatenate([net.lanes[i].shape for i in net.car_lane_ids])
    return (*xy.min(0), *xy.max(0))


def draw_fill(path: str, net, rows: np.ndarray, tiles, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PolyCollection

    dens = edge_density(net, rows)
    vmax = max(10.0, float(np.percentile(list(dens.values()), 95))) if dens else 10.0
    x0, y0, x1, y1 = frame(net)
    span = max(x1 - x0, y1 - y0, 1.0)
    fig, ax = plt.subplots(figsize=(10, 10 * max((y1 - y0) / max(x1 - x0, 1.0), 0.4) + 1))
    # lane widths in points: thin on a city, the real width on a small network
    lw = float(np.clip(2000.0 / span, 0.6, 6.0))
    internal = [net.lanes[i].shape for i in net.car_lane_ids if net.lanes[i].internal]
    ax.add_collection(LineCollection(internal, colors="0.75", linewidths=lw * 0.6, zorder=1))
    normal = [i for i in net.car_lane_ids if not net.lanes[i].internal]
    lines = LineCollection([net.lanes[i].shape for i in normal], cmap="viridis_r", linewidths=lw, zorder=2)
    lines.set_array(np.array([dens.get(net.lanes[i].edge, 0.0) for i in normal]))
    lines.set_clim(0.0, vmax)
    ax.add_collection(lines)
    for t in tiles:   # the tile cores, faintly: where each tile's vehicles come from
        cx0, cy0, cx1, cy1 = t.core
        ax.plot([cx0, cx1, cx1, cx0, cx0], [cy0, cy0, cy1, cy1, cy0], color="0.85", lw=0.4, zorder=0)
    if len(rows) and span <= BOXES_UP_TO_M:
        corners = box_corners(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4])
        ax.add_collection(PolyCollection(corners, facecolors="tab:red", edgecolors="black",
                                         linewidths=0.3, zorder=3, label=f"vehicles ({len(rows)})"))
    elif len(rows):   # a car's box would be a pixel or two: a dot each, so that one sees where they are
        size = float(np.clip(4000.0 / len(rows), 1.5, 7.0))   # thousands of dots would hide the density
        ax.scatter(rows[:, 0], rows[:, 1], s=size, c="tab:red", edgecolors="black", linewidths=0.2 if size < 4 else 0.3,
                   zorder=3, label=f"vehicles ({len(rows)})")
    bar = fig.colorbar(lines, ax=ax, fraction=0.04, pad=0.02)
    bar.set_label("density (vehicles per km of lane)")
    unit = 10 ** np.floor(np.log10(span / 5))
    scale = max(u * unit for u in (1, 2, 5) if u * unit <= span / 5)   # a round length near a fifth
    sx, sy = x0, y0 - 0.04 * span
    ax.plot([sx, sx + scale], [sy, sy], color="black", lw=3)
    ax.text(sx + scale / 2, sy - 0.015 * span, f"{scale:g} m", ha="center", va="top")
    ax.set_xlim(x0 - 0.03 * span, x1 + 0.03 * span)
    ax.set_ylim(y0 - 0.08 * span, y1 + 0.03 * span)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if len(rows):
        ax.legend(loc="upper right")
    ax.set_title(title, fontsize=10)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


__all__ = ["draw_fill", "edge_density", "frame"]
