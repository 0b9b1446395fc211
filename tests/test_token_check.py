"""A token heading against the road is named, with the lane's heading offered (never a silent U-turn)."""
from __future__ import annotations

import numpy as np

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.generation.token_check import heading_warnings
from sumo_scendiff.map.network import Network


def test_a_token_against_a_one_way_road_is_warned_with_the_lanes_heading(diagonal_net):
    net = Network.load(diagonal_net)                 # one way, from (0, 0) to (300, 300): yaw pi/4
    w = Window(150.0, 150.0, np.pi / 4)              # window frame: the road runs along +x
    along = {"x": 0.0, "y": 0.0, "heading": 0.0}
    against = {"x": 0.0, "y": 0.0, "heading": np.pi}
    assert heading_warnings(net, w, [along]) == []
    (msg,) = heading_warnings(net, w, [along, against])
    assert msg.startswith("token 1 at (150.0, 150.0)") and "0.79 rad (world)" in msg
    assert "0.00 rad in the window frame" in msg


def test_tokens_without_heading_or_off_the_road_are_not_judged(diagonal_net):
    net = Network.load(diagonal_net)
    w = Window(150.0, 150.0, 0.0)
    assert heading_warnings(net, w, [{"x": 0.0, "y": 0.0}, {"x": 40.0, "y": -40.0, "heading": 3.0}]) == []
