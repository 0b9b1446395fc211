"""Junction headings from the network (sumo_scendiff/lane_heading.py) on a real SUMO crossing."""
from __future__ import annotations

import math

import numpy as np
import torch

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.generation.lane_heading import junction_yaw
from sumo_scendiff.map.network import Network
from sumo_scendiff.map.raster import MAP_CHANNELS, render_map
from sumo_scendiff.model.detection import C_Y, box_targets, cell_centres, decode_boxes

K = 16


def _head_output(net, points):
    """A decoder output (1, 19 + 2K, 64, 64) with one box per point. The heading head is unsure
    between bins 0 and 1 (logits 3.0 / 2.9) and bin 0's residual is +0.3 rad: its argmax decodes
    0.3 rad, along no lane of the crossing."""
    y = torch.zeros(1, C_Y + 2 * K, 64 * 64)
    y[0, 0] = -10.0
    cells = cell_centres(100.0, (64, 64))
    for x, yy in points:
        c = int((cells - torch.tensor([x, yy])).norm(dim=-1).argmin())
        y[0, 0, c] = 10.0
        y[0, 1:7, c] = box_targets(torch.tensor([x, yy, 0.3, 4.5, 1.8]), cells[c], 0.1)
        y[0, C_Y, c], y[0, C_Y + 1, c] = 3.0, 2.9
        y[0, C_Y + K, c] = 0.3
    return y.reshape(1, -1, 64, 64)


def test_a_junction_box_takes_the_most_probable_lane_and_others_keep_the_head(cross_net):
    net = Network.load(cross_net)
    east = next(ln for ln in net.lanes if ln.internal and ln.car and abs(ln.shape[-1][0] - ln.shape[0][0]) > 5
                and abs(ln.shape[-1][1] - ln.shape[0][1]) < 0.1 and ln.shape[-1][0] > ln.shape[0][0])
    on_junction = tuple(np.mean(east.shape, 0))           # the middle of the eastbound lane, x ~ 0
    on_arm = (-60.0, on_junction[1])                      # the western arm, no junction
    window = Window(0.0, 0.0, 0.0)
    m = torch.from_numpy(render_map(net, window))[None]
    junction = m[:, MAP_CHANNELS.index("junction")]
    y = _head_output(net, [on_junction, on_arm])
    head = decode_boxes(y)
    yaw = junction_yaw(y, [window], net, junction)
    lanes = decode_boxes(y, yaw=yaw)
    cells = torch.nonzero(head.prob[0] > 0.5).squeeze(1)
    assert len(cells) == 2
    by_x = {round(float(head.boxes[0, c, 0])): int(c) for c in cells}
    cj, ca = by_x[min(by_x, key=lambda x: abs(x))], by_x[min(by_x)]
    assert abs(float(head.boxes[0, cj, 2]) - 0.3) < 1e-4                     # the head alone: between lanes
    assert abs(float(lanes.boxes[0, cj, 2])) < 0.02                          # the eastbound lane
    assert abs(float(lanes.boxes[0, ca, 2]) - 0.3) < 1e-4                    # off the junction: as decoded
    assert torch.equal(lanes.boxes[0, ca], head.boxes[0, ca])
    assert junction_yaw(y[:, :C_Y], [window], net, junction) is None         # no heading head: nothing to do
    assert math.isclose(float(lanes.prob[0, cj]), float(head.prob[0, cj]))
