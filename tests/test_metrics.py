"""Tests of the paper's metrics (sumo_scendiff/metrics.py): MMD², trajectory metrics, token matching."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_scendiff.core.geometry import TIMES, Window, wrap_angle
from sumo_scendiff.core.scene import Scene, rotate_scene
from sumo_scendiff.evaluate.baselines import LaneUniform
from sumo_scendiff.evaluate.metrics import (
    MMD_SIGMAS,
    agent_features,
    agents_per_scene_emd,
    evaluate_scenes,
    gaussian_kernel,
    lane_heading_difference,
    match_agents,
    mean_scene_mmd2,
    mmd2,
    precision_recall_f1,
    token_metrics,
    traj_on_drivable,
)
from sumo_scendiff.map.network import Network

CENTRE = Window(100.0, 100.0, 0.3, 100.0)  # the middle of the 3x3 grid (0..200 m), rotated


def make_scene(window: Window, xy, yaw, speed=None, final_speed=None, final_mask=None) -> Scene:
    """Agents with constant poses (no motion needed for these metrics)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    n = len(xy)
    yaw = np.broadcast_to(np.asarray(yaw, float), (n,))
    sp = np.zeros((n, len(TIMES)))
    if speed is not None:
        sp[:] = np.asarray(speed, float)[:, None]
    if final_speed is not None:
        sp[:, 4] = final_speed
    mask = np.ones((n, len(TIMES)), bool)
    if final_mask is not None:
        mask[:, 4] = final_mask
    boxes = np.column_stack([xy, yaw, np.full(n, 4.5), np.full(n, 1.8)])
    traj = np.repeat(np.column_stack([xy, yaw])[:, None], len(TIMES), 1)
    return Scene(window, boxes, traj, mask, sp, np.zeros(n))


# ---- MMD ---------------------------------------------------------------------------------------
def test_mmd2_identical_zero_symmetric_positive():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(7, 2)), rng.normal(size=(5, 2))
    assert mmd2(a, a, 1.0) == pytest.approx(0.0, abs=1e-12)
    assert mmd2(a, b, 1.0) == pytest.approx(mmd2(b, a, 1.0))
    assert mmd2(a, a + 3.0, 1.0) > 0.5
    assert mmd2(a, b, 1.0) >= 0.0


def test_mmd2_one_vs_one_hand_value():
    # k(a,a) = k(b,b) = 1; k(a,b) = exp(-25 / (2 * 25)): MMD² = 2 - 2 exp(-0.5)
    assert mmd2([[0.0, 0.0]], [[3.0, 4.0]], 5.0) == pytest.approx(2 - 2 * math.exp(-0.5))
    # two vs one, by the V-statistic: 1/4 (2 + 2 k(a1,a2)) + 1 - 2/2 (k(a1,b) + k(a2,b))
    k = lambda d2: math.exp(-d2 / 2)  # noqa: E731  sigma = 1
    want = 0.25 * (2 + 2 * k(4.0)) + 1 - (k(1.0) + k(1.0))
    assert mmd2([[0.0, 0.0], [2.0, 0.0]], [[1.0, 0.0]], 1.0) == pytest.approx(want)


def test_joint_kernel_is_product_of_marginals():
    rng = np.random.default_rng(1)
    s1 = make_scene(CENTRE, rng.uniform(-50, 50, (6, 2)), rng.uniform(-3, 3, 6), rng.uniform(0, 15, 6))
    s2 = make_scene(CENTRE, rng.uniform(-50, 50, (4, 2)), rng.uniform(-3, 3, 4), rng.uniform(0, 15, 4))
    f1, f2 = agent_features(s1), agent_features(s2)
    prod = np.ones((6, 4))
    for k in ("position", "heading", "velocity"):
        prod *= gaussian_kernel(f1[k], f2[k], MMD_SIGMAS[k])
    assert np.allclose(gaussian_kernel(f1["joint"], f2["joint"], 1.0), prod)
    assert np.allclose(np.linalg.norm(f1["heading"], axis=1), 1.0)
    assert np.allclose(np.linalg.norm(f1["velocity"], axis=1), s1.speed[:, 2])


def test_scene_mmd_per_scene_average_and_empty_excluded():
    a = make_scene(CENTRE, [[0, 0], [10, 0]], 0.0, [5, 5])
    b = make_scene(CENTRE, [[0, 3], [10, 0]], 0.0, [5, 5])
    empty = Scene.empty(CENTRE)
    r = mean_scene_mmd2([a, empty, a], [b, b, a])
    assert r["mmd_scenes"] == 2
    assert r["mmd2_position"] == pytest.approx(mmd2(a.boxes[:, :2], b.boxes[:, :2], 5.0) / 2)
    assert r["mmd2_heading"] == pytest.approx(0.0, abs=1e-12)


def test_scene_mmd_uses_ground_truth_frame():
    rng = np.random.default_rng(2)
    gen = make_scene(CENTRE, rng.uniform(-40, 40, (5, 2)), rng.uniform(-3, 3, 5), rng.uniform(0, 9, 5))
    gt = make_scene(CENTRE, rng.uniform(-40, 40, (6, 2)), rng.uniform(-3, 3, 6), rng.uniform(0, 9, 6))
    plain = mean_scene_mmd2([gen], [gt])
    rotated = mean_scene_mmd2([rotate_scene(gen, 1.1)], [gt])
    for k in plain:
        assert rotated[k] == pytest.approx(plain[k])


def test_agents_per_scene_emd():
    assert agents_per_scene_emd([1, 2, 3], [2, 3, 4]) == pytest.approx(1.0)
    assert agents_per_scene_emd([0, 5], [5, 0]) == pytest.approx(0.0)


# ---- trajectory metrics ------------------------------------------------------------------------
def test_traj_metrics_lane_uniform_on_road_and_off_road(grid):
    lu = LaneUniform(grid, seed=3)
    scenes = [lu.generate(CENTRE, n=10, index=i) for i in range(5)]
    assert sum(len(s) for s in scenes) == 50
    assert traj_on_drivable(scenes, grid) == 1.0
    mean, excluded = lane_heading_difference(scenes, grid)
    assert mean < 0.02 and excluded == 0.0
    off = []
    for s in scenes:  # the same agents 1 km away from any road
        t = s.traj.copy()
        t[..., 0] += 1000.0
        off.append(Scene(s.window, s.boxes, t, s.traj_mask, s.speed, s.vclass))
    assert traj_on_drivable(off, grid) == 0.0
    mean, excluded = lane_heading_difference(off, grid)
    assert math.isnan(mean) and excluded == 1.0


def test_traj_on_drivable_counts_only_observed_waypoints(grid):
    s = LaneUniform(grid, seed=4).generate(CENTRE, n=3, index=0)
    t, m = s.traj.copy(), s.traj_mask.copy()
    t[0, 0, 0] += 1000.0   # one waypoint off road ...
    assert traj_on_drivable([Scene(s.window, s.boxes, t, m, s.speed, s.vclass)], grid) == pytest.approx(14 / 15)
    m[0, 0] = False        # ... but unobserved
    assert traj_on_drivable([Scene(s.window, s.boxes, t, m, s.speed, s.vclass)], grid) == 1.0


def test_lane_heading_difference_reversed_is_pi(diagonal_net):
    net = Network.load(diagonal_net)  # one-way road: reversing a vehicle puts it against every lane
    w = Window(150.0, 150.0, -0.4, 100.0)
    scenes = [LaneUniform(net, seed=5).generate(w, n=8, index=i) for i in range(3)]
    mean, excluded = lane_heading_difference(scenes, net)
    assert mean < 0.01 and excluded == 0.0
    rev = [Scene(s.window, s.boxes, np.concatenate([s.traj[..., :2], wrap_angle(s.traj[..., 2:] + np.pi)], -1),
                 s.traj_mask, s.speed, s.vclass) for s in scenes]
    mean, excluded = lane_heading_difference(rev, net)
    assert mean == pytest.approx(math.pi, abs=0.01) and excluded == 0.0


def test_evaluate_scenes_ground_truth_against_itself(grid):
    lu = LaneUniform(grid, seed=6)
    gt = [lu.generate(CENTRE, index=i) for i in range(6)] + [Scene.empty(CENTRE)]
    r = evaluate_scenes(gt, gt, grid)
    assert r["scenes"] == 7 and r["mmd_scenes"] == sum(len(s) > 0 for s in gt)
    for k in ("mmd2_position", "mmd2_heading", "mmd2_velocity", "mmd2_joint", "agents_per_scene_emd"):
        assert r[k] == pytest.approx(0.0, abs=1e-9)
    assert r["traj_on_drivable"] == r["gt_only"]["traj_on_drivable"] == 1.0
    with pytest.raises(ValueError):
        evaluate_scenes(gt[:2], gt[:3], grid)
    with pytest.raises(ValueError):
        evaluate_scenes([Scene.empty(Window(0.0, 0.0))], gt[:1], grid)


# ---- token matching ----------------------------------------------------------------------------
def test_match_gates_distance_and_heading():
    tok = np.array([[0.0, 0.0, 0.0]])
    assert len(match_agents(np.array([[2.1, 0.0, 0.0]]), tok)[0]) == 1
    assert len(match_agents(np.array([[2.3, 0.0, 0.0]]), tok)[0]) == 0      # beyond 2.2 m
    assert len(match_agents(np.array([[0.0, 0.0, 0.19]]), tok)[0]) == 1
    assert len(match_agents(np.array([[0.0, 0.0, 0.21]]), tok)[0]) == 0     # beyond 0.2 rad
    assert len(match_agents(np.array([[0.0, 0.0, math.pi]]), np.array([[0.0, 0.0, -math.pi]]))[0]) == 1
    # the only assignment of 2 x 2 uses an infeasible pair: it must be dropped, not reported
    g, t = match_agents(np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0]]),
                        np.array([[1.0, 0.0, 0.0], [0.0, 30.0, 0.0]]))
    assert g.tolist() == [0] and t.tolist() == [0]
    assert len(match_agents(np.zeros((0, 3)), tok)[0]) == 0


def test_hungarian_beats_greedy():
    # greedy (closest pair first) takes g0-t1 (0.9 m) and leaves g1 with nothing: 1 match.
    # Hungarian: g0-t0 (1.1 m) and g1-t1 (2.0 m): 2 matches.
    tok = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    gen = np.array([[1.1, 0.0, 0.0], [4.0, 0.0, 0.0]])
    g, t = match_agents(gen, tok)
    assert sorted(zip(g.tolist(), t.tolist())) == [(0, 0), (1, 1)]
    # among maximum matchings, the least total distance
    g, t = match_agents(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.array([[1.1, 0, 0], [0.1, 0, 0]]))
    assert sorted(zip(g.tolist(), t.tolist())) == [(0, 1), (1, 0)]


def test_precision_recall_f1_hand_case():
    r = precision_recall_f1(tp=3, fp=1, fn=2)
    assert r["precision"] == pytest.approx(0.75) and r["recall"] == pytest.approx(0.6)
    assert r["f1"] == pytest.approx(2 * 0.75 * 0.6 / 1.35)
    assert precision_recall_f1(0, 2, 3)["f1"] == 0.0


def test_token_metrics_counts_and_speed_mae():
    w = Window(0.0, 0.0, 0.0, 100.0)
    tok = make_scene(w, [[0, 0], [10, 0], [20, 0]], 0.0, [5.0, 8.0, 3.0], [6.0, 9.0, 1.0])
    # matches tokens 0 and 1 (speed errors 1 and 2; final: token 1 pair unobserved), one extra agent
    gen = make_scene(w, [[0.5, 0], [10, 1.0], [40, 0]], [0.0, 0.1, 0.0], [6.0, 6.0, 0.0],
                     [8.0, 0.0, 0.0], final_mask=[True, False, True])
    tok2 = make_scene(w, [[0, 0]], 0.0, [4.0], [4.0])
    gen2 = make_scene(w, [[0, 0]], 2.0, [4.0], [4.0])  # heading off by 2 rad: no match
    r = token_metrics([gen, gen2], [tok, tok2])
    assert (r["tp"], r["fp"], r["fn"]) == (2, 2, 2)
    assert r["match_rate"] == r["recall"] == pytest.approx(0.5)
    assert r["precision"] == pytest.approx(0.5) and r["f1"] == pytest.approx(0.5)
    assert r["additional_per_scene"] == pytest.approx(1.0)
    assert r["speed_mae"] == pytest.approx(1.5)
    assert r["final_speed_mae"] == pytest.approx(2.0) and r["final_speed_pairs"] == 1
    # the tokens' frame does not matter
    r2 = token_metrics([gen, gen2], [rotate_scene(tok, 0.7), tok2])
    assert (r2["tp"], r2["fp"], r2["fn"]) == (2, 2, 2)


def test_signal_standing_shares_at_red_and_green(cross_net):
    """A car standing 5 m before its red stop line and one driving towards its green one count as
    standing at red 1/1 and at green 0/1; one 120 m before the line counts for neither; a scene
    without lights for nothing."""
    import math

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import Scene
    from sumo_scendiff.evaluate.metrics import signal_standing
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.map.signals import signal_links
    net = Network.load(cross_net)
    east = next(ln for ln in net.lanes if ln.edge == "wc")
    north = next(ln for ln in net.lanes if ln.edge == "sc")
    links = signal_links(net)
    tls = links[0].tls
    state = ["G"] * (max(ln.index for ln in links) + 1)
    for ln in links:
        if ln.lane == net.lane_index[east.id]:
            state[ln.index] = "r"
    x_e, y_e = (float(v) for v in east.shape[-1])
    x_n, y_n = (float(v) for v in north.shape[-1])
    boxes = np.array([[x_e - 5.0, y_e, 0.0, 4.5, 1.8], [x_n, y_n - 20.0, math.pi / 2, 4.5, 1.8],
                      [x_e - 120.0, y_e, 0.0, 4.5, 1.8]])
    speed = np.array([[0.0] * 5, [9.0] * 5, [0.0] * 5])
    scene = Scene(Window(0.0, 0.0, 0.0, 400.0), boxes, np.repeat(boxes[:, None, :3], 5, 1), np.ones((3, 5), bool),
                  speed, np.zeros(3), "cross")
    got = signal_standing([scene], net, [{tls: "".join(state)}])
    assert (got["standing_red"], got["at_red"], got["standing_green"], got["at_green"]) == (1.0, 1, 0.0, 1)
    none = signal_standing([scene], net, [None])
    assert none["at_red"] == none["at_green"] == 0 and np.isnan(none["standing_red"])
