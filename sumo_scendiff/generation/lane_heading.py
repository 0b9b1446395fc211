"""Junction headings from the network: a decoded box centred on a junction takes the heading of the
lane through it that the decoder's heading head finds most probable.

    yaw = junction_yaw(y, windows, net, junction)        # (B, H*W) or None
    dec = decode_boxes(y, size, yaw=yaw)

Inside a junction the lanes cross, and the heading head's posterior there is broad (median 0.15 on
the right 22.5-degree bin, spread over 3-4 bins: docs/history.md, "How the shipped checkpoint was found", item
13); its argmax often lies between two lanes, and a box heading along no lane is matched to no
agent. The network knows which headings are possible at that point: the car lanes within
``radius`` m of the decoded centre. Each is scored by the head's posterior at its heading
(:func:`~sumo_scendiff.model.heading.heading_probability`) and the best one replaces the argmax.
Boxes off junctions, and decoders without a heading head, are left as decoded.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np
import torch

from ..core.geometry import Window, wrap_angle
from ..model.detection import C_Y, decode_boxes, on_junction
from ..model.heading import decode_heading, heading_probability

if TYPE_CHECKING:
    from ..map.network import Network


def junction_yaw(y: torch.Tensor, windows: Sequence[Window], net: "Network", junction: torch.Tensor,
                 size: float = 100.0, min_prob: float = 0.5, radius: float = 1.5) -> torch.Tensor | None:
    """Per cell of ``y`` (B, 19 + 2K, H, W), the box heading (B, H*W) in each window's scene frame:
    the head's argmax, or on a junction (``junction`` (B, h, w), the map's junction channel) for a
    cell with box probability >= ``min_prob``, the heading of the car lane within ``radius`` m of its
    decoded centre with the highest posterior. None without a heading head."""
    if y.shape[1] <= C_Y:
        return None
    yf = y.flatten(2).transpose(1, 2)                       # (B, cells, C)
    yaw = decode_heading(yf[..., C_Y:])
    dec = decode_boxes(y[:, :C_Y], size, yaw=yaw)
    scene, cells = torch.nonzero(dec.prob >= min_prob, as_tuple=True)   # every window's, in order
    on = on_junction(dec.boxes[scene, cells], scene, junction, size) if len(cells) else cells.bool()
    scene, cells = scene[on].numpy(), cells[on].numpy()
    if len(cells) == 0:
        return yaw
    xy = dec.boxes.numpy()[scene, cells, :2].astype(np.float64)
    for i in np.unique(scene):
        xy[scene == i] = windows[i].scene_to_world(xy[scene == i])
    point, _, heading = net.lane_headings_at(xy, radius)
    if len(point) == 0:
        return yaw
    turn = np.array([w.yaw for w in windows], np.float64)[scene[point]]
    cand = np.asarray(wrap_angle(heading - turn), np.float32)
    score = heading_probability(yf[scene[point], cells[point], C_Y:], torch.from_numpy(cand)).numpy()
    # per decoded centre its best lane: the highest score, the first lane found on a tie
    order = np.lexsort((np.arange(len(point)), -score, point))
    best = order[np.r_[True, point[order][1:] != point[order][:-1]]]
    yaw[scene[point[best]], cells[point[best]]] = torch.from_numpy(cand[best])
    return yaw
