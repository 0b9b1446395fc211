"""Scenario Dreamer's JSD set (sumo_scendiff/evaluate/jsd.py): histograms, the squared
Jensen–Shannon distance, lane features on a real netconvert network, the five-circle collision test."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_scendiff.core.geometry import TIMES, Window
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.evaluate.jsd import (
    JSD_BINS,
    collision_share,
    colliding,
    evaluate_jsd,
    histogram,
    jsd,
    lane_features,
    vehicle_features,
)
from sumo_scendiff.map.network import Network


def scene(window: Window, boxes, speed=0.0) -> Scene:
    """Standing boxes (x, y, yaw, length, width) in ``window``'s scene frame at ``speed``."""
    b = np.asarray(boxes, float).reshape(-1, 5)
    n = len(b)
    traj = np.repeat(b[:, None, :3], len(TIMES), 1)
    return Scene(window, b, traj, np.ones((n, len(TIMES)), bool), np.full((n, len(TIMES)), speed), np.zeros(n))


W = Window(0.0, 0.0, 0.0, 100.0)


def test_histogram_clips_into_the_edge_bins():
    h = histogram([-3.0, 0.2, 0.7, 49.5, 80.0], 0.0, 50.0, 1.0)
    assert len(h) == 50 and h[0] == 3 and h[49] == 2 and h.sum() == 5


def test_jsd_is_zero_for_equal_histograms_ln2_for_disjoint_and_symmetric():
    a, b = np.array([1.0, 1.5, 2.5]), np.array([10.5, 11.5])
    assert jsd(a, a, 0, 50, 1) == pytest.approx(0.0, abs=1e-12)
    assert jsd(a, b, 0, 50, 1) == pytest.approx(math.log(2))      # natural log: at most ln 2
    c = np.array([1.2, 10.2])
    assert jsd(a, c, 0, 50, 1) == pytest.approx(jsd(c, a, 0, 50, 1))
    # hand value: P = (1, 0), Q = (1/2, 1/2), M = (3/4, 1/4)
    want = 0.5 * math.log(1 / 0.75) + 0.5 * (0.5 * math.log(0.5 / 0.75) + 0.5 * math.log(0.5 / 0.25))
    assert jsd([0.5], [0.5, 1.5], 0, 2, 1) == pytest.approx(want)
    assert math.isnan(jsd([], a, 0, 50, 1))


def test_collision_by_five_circles():
    # side by side 1.5 m apart (widths 1.8): (1.8 + 1.8) / sqrt(3.8) = 1.85 m > 1.5: colliding
    assert colliding(scene(W, [[0, 0, 0, 4.5, 1.8], [0, 1.5, 0, 4.5, 1.8]])).tolist() == [True, True]
    # 2 m apart: not; nose to tail 5 m apart (end circles 2.3 m apart): not
    assert not colliding(scene(W, [[0, 0, 0, 4.5, 1.8], [0, 2.0, 0, 4.5, 1.8]])).any()
    assert not colliding(scene(W, [[0, 0, 0, 4.5, 1.8], [5.0, 0, 0, 4.5, 1.8]])).any()
    # a truck's rear circle reaches a car standing across its tail: only the length's circles see it
    truck_and_car = scene(W, [[0, 0, 0, 12.0, 2.5], [-6.5, 0, np.pi / 2, 4.5, 1.8], [30, 0, 0, 4.5, 1.8]])
    assert colliding(truck_and_car).tolist() == [True, True, False]
    assert collision_share([truck_and_car, scene(W, [])]) == pytest.approx(2 / 3)


def test_lane_features_on_a_real_road(diagonal_net):
    net = Network.load(diagonal_net)
    lane = net.lanes[[ln.car for ln in net.lanes].index(True)]
    mid = lane.shape.mean(0)
    yaw = math.atan2(*(lane.shape[-1] - lane.shape[0])[::-1])
    normal = np.array([-math.sin(yaw), math.cos(yaw)])
    window = Window(float(mid[0]), float(mid[1]), 0.0, 100.0)
    boxes = [[0, 0, yaw + 0.1, 4.5, 1.8],                        # on the centre line, 0.1 rad off
             [*(0.6 * normal + [30, 30]), yaw + math.pi, 4.5, 1.8],  # 0.6 m off a centre line, reversed
             [*(40 * normal), yaw, 4.5, 1.8]]                      # far from every lane
    d, h = lane_features([scene(window, boxes)], net)
    assert len(d) == 2 and d[0] == pytest.approx(0.0, abs=0.05) and d[1] == pytest.approx(0.6, abs=0.05)
    assert h[0] == pytest.approx(math.degrees(0.1), abs=1.0) and abs(h[1]) == pytest.approx(180.0, abs=1.0)


def test_evaluate_jsd_against_itself_and_a_shifted_fleet(diagonal_net):
    net = Network.load(diagonal_net)
    rng = np.random.default_rng(0)
    ref = [scene(W, np.column_stack([rng.uniform(-40, 40, (6, 2)), rng.uniform(-3, 3, 6),
                                     rng.choice([3.9, 4.6, 5.1], 6), np.full(6, 1.8)]), speed=8.0)
           for _ in range(5)]
    same = evaluate_jsd(ref, ref, net)
    assert set(same) == {f"jsd_{k}" for k in JSD_BINS} | {"collision"}
    assert all(same[f"jsd_{k}"] == pytest.approx(0.0, abs=1e-12) for k in ("nearest", "length", "width", "speed"))
    trucks = [scene(W, np.column_stack([s.boxes[:, :3], np.full(len(s), 12.0), np.full(len(s), 2.5)]), speed=20.0)
              for s in ref]
    other = evaluate_jsd(trucks, ref, net, vehicle_features(ref, net))
    # disjoint lengths, widths and speeds: ln 2 at the scale of 100
    for k in ("length", "width", "speed"):
        assert other[f"jsd_{k}"] == pytest.approx(100 * math.log(2))
    assert other["jsd_nearest"] == pytest.approx(0.0, abs=1e-12)   # the same centres
