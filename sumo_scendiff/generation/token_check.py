"""Tokens checked against the network before generation: a heading that runs against every lane at
the token's position is most likely a mistake (east instead of west), and the model would turn the
vehicle around to fit the road. The user is told, with the lane's heading to use instead.
"""
from __future__ import annotations

import numpy as np

from ..core.geometry import Window, wrap_angle

AGAINST = np.pi / 2     # rad: a heading further than this from every lane runs against the road
RADIUS = 2.0            # m: lanes this close to the token's position count


def heading_warnings(net, window: Window, tokens) -> list[str]:
    """One line per token (window frame) whose heading disagrees with every car lane at its position."""
    out = []
    for i, t in enumerate(tokens or ()):
        if not isinstance(t, dict) or any(t.get(k) is None for k in ("x", "y", "heading")):
            continue
        xy = window.scene_to_world(np.array([[float(t["x"]), float(t["y"])]]))
        yaw = float(window.yaw_to_world(float(t["heading"])))
        _, _, heads = net.lane_headings_at(xy, radius=RADIUS)
        if len(heads) == 0:
            continue
        diff = np.abs(wrap_angle(yaw - heads))
        if diff.min() > AGAINST:
            lane = float(heads[int(np.argmin(diff))])
            scene = float(wrap_angle(lane - window.yaw))
            out.append(f"token {i} at ({xy[0, 0]:.1f}, {xy[0, 1]:.1f}): heading {yaw:.2f} rad (world) runs "
                       f"against every lane there; the lane's heading is {lane:.2f} rad (world), "
                       f"{scene:.2f} rad in the window frame — the model may turn this vehicle around")
    return out
