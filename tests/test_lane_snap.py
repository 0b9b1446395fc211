"""Lane snapping (sumo_scendiff/lane_snap.py) and the vectorised lane matcher on real SUMO networks."""
from __future__ import annotations

import math

import numpy as np
import shapely

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.generation.generator import (
    GenerationConfig,
    ScenarioGenerator,
    speeds_from_traj,
)
from sumo_scendiff.generation.lane_snap import snap_to_lanes, walk_lanes
from sumo_scendiff.generation.scene_passes import build_scene
from sumo_scendiff.map.network import Network
from sumo_scendiff.tokens.encoding import agent_tokens_from_dicts


def test_match_poses_is_lookup_for_many_poses(cross_net):
    net = Network.load(cross_net)
    rng = np.random.default_rng(3)
    xy = rng.uniform(-40, 40, (400, 2))
    xy[:200, 1] = rng.normal(0, 2.5, 200)               # half of them near the east-west road
    yaw = rng.uniform(-np.pi, np.pi, 400)
    m = net.match_poses(xy, yaw)
    found = 0
    for k, ((x, y), a) in enumerate(zip(xy, yaw)):
        hit = net.lookup(x, y, a)
        if hit is None:
            assert m.lane[k] == -1 and tuple(m.xy[k]) == (x, y)
            continue
        found += 1
        assert net.lanes[m.lane[k]].id == hit[0].id
        assert math.isclose(m.pos[k], hit[1], abs_tol=1e-9) and math.isclose(m.lateral[k], hit[2], abs_tol=1e-9)
        line = net.lines[m.lane[k]]
        assert line.distance(shapely.Point(m.xy[k])) < 1e-6          # the projected point is on it
    assert 60 < found < 390                                          # both kinds of pose were tried


def _diag_window():
    return Window(150.0, 150.0, math.pi / 4)           # the scene's x axis along the road


def test_moving_agent_lands_on_its_centre_line_with_its_speed(diagonal_net):
    net = Network.load(diagonal_net)
    win = _diag_window()
    right = net.lookup(150.0, 150.0, math.pi / 4)[0]   # the lane under the window's centre
    # a lane centre in scene y: the road's two lanes lie at y = -1.6 and +1.6 of the edge's axis
    lane_y = float(win.world_to_scene(right.shape.mean(0))[1])
    t = np.arange(-2, 3, dtype=np.float64)
    traj = np.zeros((1, 5, 3))
    traj[0, :, 0] = 10.0 * t                            # 10 m/s along the road
    traj[0, :, 1] = lane_y + 0.6                        # 0.6 m off its centre line
    traj[0, :, 2] = 0.1                                 # tilted 0.1 rad against the lane
    boxes = np.array([[0.0, lane_y + 0.6, 0.1, 4.5, 1.8]])
    b, tr, snapped = snap_to_lanes(boxes, traj, win, net)
    assert snapped.all()
    assert np.allclose(tr[0, :, 1], lane_y, atol=1e-6) and np.allclose(tr[0, :, 2], 0.0, atol=1e-6)
    assert np.allclose(b[0, :3], tr[0, 2]) and np.allclose(b[0, 3:], [4.5, 1.8])
    v = speeds_from_traj(tr.astype(np.float32), np.ones((1, 5), bool))
    assert np.allclose(v, 10.0, atol=1e-3)


def test_poses_without_an_agreeing_lane_stay_as_decoded(diagonal_net):
    net = Network.load(diagonal_net)
    win = _diag_window()
    traj = np.zeros((2, 5, 3))
    traj[0, :, 0] = -5.0 * np.arange(-2, 3)             # driving against both lanes (one-way road)
    traj[0, :, 2] = math.pi
    traj[1, :, :2] = (0.0, 12.0)                        # 12 m beside the road
    boxes = np.c_[traj[:, 2], [[4.5, 1.8], [4.5, 1.8]]]
    b, tr, snapped = snap_to_lanes(boxes, traj, win, net)
    assert not snapped.any()
    assert np.array_equal(tr, traj) and np.array_equal(b, boxes)


def test_a_standing_car_on_crossing_lanes_stays_standing(cross_net):
    net = Network.load(cross_net)
    win = Window(0.0, 0.0, 0.0)
    rng = np.random.default_rng(0)
    traj = np.zeros((1, 5, 3))
    traj[0, :, :2] = (1.0, -1.0) + rng.normal(0, 0.1, (5, 2))    # inside the junction, jittering
    traj[0, :, 2] = 0.05 * rng.normal(size=5)
    _, tr, snapped = snap_to_lanes(np.c_[traj[:, 2], [[4.5, 1.8]]], traj, win, net)
    assert snapped.all()
    assert np.ptp(tr[0], axis=0).max() == 0.0           # one pose: speed 0, as decoded
    assert speeds_from_traj(tr.astype(np.float32), np.ones((1, 5), bool)).max() == 0.0


def test_generator_snaps_by_default_and_can_be_told_not_to(cross_net):
    net = Network.load(cross_net)
    windows = [Window(0.0, 0.0, 0.3), Window(-50.0, 0.0, 0.0)]
    on = ScenarioGenerator.load(config=GenerationConfig(steps=4, threshold=0.5))
    snapped = on.generate(net, windows, seed=1)
    raw = on.generate(net, windows, seed=1, config=GenerationConfig(steps=4, threshold=0.5, lane_snap=False))
    assert sum(len(s) for s in raw) > 0
    off_centre = []
    for scenes, out in ((snapped, []), (raw, off_centre)):
        for s in scenes:
            xy = s.window.scene_to_world(s.boxes[:, :2].astype(np.float64))
            m = net.match_poses(xy, s.window.yaw_to_world(s.boxes[:, 2].astype(np.float64)))
            out.extend(m.lateral[m.lane >= 0])
        if scenes is snapped:
            assert len(out) and max(out) < 2e-3         # on a centre line (poses rounded to mm)
    assert max(off_centre) > 0.05                       # as decoded, they were not


def _centre(net):
    return np.asarray(next(j for j in net.junctions if j.id == "c").polygon.centroid.coords[0])


def test_walk_lanes_branches_through_the_junction_and_back(cross_net):
    net = Network.load(cross_net)
    wc = net.lane_index["wc_0"]
    length = net.lines[wc].length
    ahead = walk_lanes(net, wc, length - 2.0, 20.0)           # 2 m before the stop line, 20 m on
    reached = {net.lanes[ln].edge for ln, _ in ahead}
    assert {"ce", "cs", "cn"} <= reached                    # straight, right, left (via internal lanes)
    for ln, p in ahead:                                     # 20 m along every branch, not further
        assert 0.0 <= p <= net.lines[ln].length
    back = {net.lanes[ln].edge for ln, _ in walk_lanes(net, net.lane_index["ce_0"], 1.0, -15.0)}
    assert "sc" in back                             # back through the short right turn onto its approach
    assert back <= {"sc", "wc", "nc"} | {e for e in back if e.startswith(":c_")}   # only what leads onto ce
    assert walk_lanes(net, wc, 10.0, 5.0) == [(wc, 15.0)]


def test_a_waypoint_off_every_lane_follows_the_lane_graph(cross_net):
    net = Network.load(cross_net)
    c = _centre(net)
    win = Window(float(c[0]), float(c[1]), 0.0)
    traj = np.zeros((1, 5, 3))
    traj[0, :3, :2] = [(-30, -1.6), (-20, -1.6), (-10, -1.6)]   # eastbound towards the junction
    traj[0, 3] = (-1.0, -4.0, -0.6)                             # turning right inside it
    traj[0, 4] = (2.0, -12.0, 0.0)                              # beside the southbound lane, facing east:
    assert net.match_poses(win.scene_to_world(traj[0, 4:, :2]), [0.0]).lane[0] == -1   # no lane agrees
    _, tr, snapped = snap_to_lanes(np.c_[traj[:, 2], [[4.5, 1.8]]], traj, win, net)
    assert snapped.all()
    end = net.match_poses(win.scene_to_world(tr[0, 4:, :2]), [tr[0, 4, 2]])
    assert net.lanes[end.lane[0]].edge == "cs" and end.lateral[0] < 1e-6     # on the southbound lane
    assert abs(tr[0, 4, 2] + math.pi / 2) < 1e-3                            # heading south
    step = np.linalg.norm(traj[0, 4, :2] - traj[0, 3, :2])
    assert abs(np.linalg.norm(tr[0, 4, :2] - tr[0, 3, :2]) - step) < 2.0     # about the decoded step


def test_generator_removes_agents_on_no_lane_unless_a_token_asked(cross_net):
    net = Network.load(cross_net)
    c = _centre(net)
    win = Window(float(c[0]), float(c[1]), 0.0)
    poses = np.array([(-30.0, -1.6, 0.0),     # on the eastbound lane
                      (-30.0, -20.0, 0.0),    # 18 m off the road
                      (30.0, -20.0, 0.0),     # off the road, where a token asked for a vehicle
                      (-40.0, -4.0, math.pi)])  # against the eastbound lane, the westbound 4 m away
    boxes = np.c_[poses, np.tile([4.5, 1.8], (4, 1))].astype(np.float32)
    traj = np.repeat(poses[:, None], 5, 1).astype(np.float32)
    prob = np.array([0.9, 0.95, 0.85, 0.99], np.float32)
    tokens = agent_tokens_from_dicts([{"x": 30.0, "y": -20.0}])
    scene = build_scene(win, prob, boxes, traj, GenerationConfig(), net, tokens)
    assert len(scene) == 2 and scene.meta["off_lane_removed"] == 2
    assert sorted(np.round(scene.boxes[:, 0]).tolist()) == [-30.0, 30.0]
    raw = build_scene(win, prob, boxes, traj, GenerationConfig(lane_snap=False), net, tokens)
    assert len(raw) == 4 and raw.meta["off_lane_removed"] == 0
