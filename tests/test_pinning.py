"""Pinned tokens: synthesised trajectories, inpainting in the denoiser, the shipped model placing them."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from sumo_scendiff.core.geometry import T0, Window
from sumo_scendiff.generation.generator import (
    GenerationConfig,
    ScenarioGenerator,
    speeds_from_traj,
)
from sumo_scendiff.generation.pinning import (
    is_pinnable,
    pace_to_pins,
    pinned_latent,
    pinned_poses,
    retime,
    token_trajectories,
    turn_to_pins,
)
from sumo_scendiff.generation.scene_passes import build_scene
from sumo_scendiff.map.network import Network
from sumo_scendiff.model.edm import SAMPLERS, inpainted, karras_sigmas

CAR = {"x": 3.0, "y": -2.0, "heading": 0.5, "length": 4.5, "width": 1.8}


def test_straight_constant_speed_trajectory():
    boxes, traj, mask = token_trajectories([{**CAR, "speed": 8.0}])
    assert mask.all() and np.allclose(boxes[0], [3, -2, 0.5, 4.5, 1.8])
    along = (traj[0, :, :2] - [3, -2]) @ [np.cos(0.5), np.sin(0.5)]
    assert np.allclose(along, [-16, -8, 0, 8, 16], atol=1e-3)
    assert np.allclose(traj[0, :, 2], 0.5)


def test_stopping_turning_and_starting_trajectories():
    (_, stop, _), (_, turn, _), (_, start, _) = (
        token_trajectories([{**CAR, "speed": 5.0, "final_speed": 0.0}]),
        token_trajectories([{**CAR, "speed": 10.0, "heading_to_final": 0.3}]),
        token_trajectories([{**CAR, "speed": 0.0, "final_speed": 4.0}]))
    # SUMO's Euler step: p(t) - p(t-1) = v(t), so 5 m/s stopping in 2 s moves 2.5 + 0 m
    assert np.hypot(*(stop[0, 4, :2] - stop[0, T0, :2])) == pytest.approx(2.5, abs=1e-3)
    chord = turn[0, 4, :2] - turn[0, T0, :2]
    assert np.arctan2(chord[1], chord[0]) - 0.5 == pytest.approx(0.3, abs=1e-6)        # heading_to_final
    assert turn[0, 4, 2] == pytest.approx(0.5 + 0.6)                                     # arc: twice the chord
    assert np.allclose(start[0, :T0 + 1, :2], [3, -2])                                   # never backwards
    assert np.hypot(*(start[0, 4, :2] - [3, -2])) == pytest.approx(2.0 + 4.0, abs=1e-3)


@pytest.mark.parametrize("tok", [{"speed": 8.0}, {"speed": 5.0, "final_speed": 0.0},
                                 {"speed": 0.0, "final_speed": 4.0}, {"speed": 12.0, "final_speed": 7.0}])
def test_generated_speeds_read_back_the_token_speeds(tok):
    """speeds_from_traj (what a generated scene reports) inverts the synthesis: speed at t = 0,
    final_speed at +2 s, a constant acceleration in between."""
    from sumo_scendiff.generation.generator import speeds_from_traj
    _, traj, mask = token_trajectories([{**CAR, **tok}])
    v = speeds_from_traj(traj, mask)[0]
    v2 = tok.get("final_speed", tok["speed"])
    assert v[T0] == pytest.approx(tok["speed"], abs=1e-6) and v[-1] == pytest.approx(v2, abs=1e-6)
    assert v[T0 + 1] == pytest.approx((tok["speed"] + v2) / 2, abs=1e-6)


def test_pinnable_needs_pose_size_and_speed():
    assert is_pinnable({**CAR, "speed": 0.0})
    assert not is_pinnable(CAR)
    assert not is_pinnable({**CAR, "speed": float("nan")})


@pytest.mark.parametrize("name", sorted(SAMPLERS))
def test_inpainting_reaches_the_known_cells_and_leaves_the_rest(name):
    def D(z, sigma, **_):
        return 0.3 * z / (1 + sigma ** 2) ** 0.5
    z_t = torch.randn(2, 4, 8, 8, generator=torch.Generator().manual_seed(0)) * 20
    known = torch.randn(2, 4, 8, 8, generator=torch.Generator().manual_seed(1))
    mask = torch.zeros(2, 1, 8, 8)
    mask[0, :, 2:4, 5:7] = 1
    sigmas = karras_sigmas(12)
    # (the stochastic samplers draw the same fresh noise in both runs)
    free = SAMPLERS[name](D, z_t, sigmas, generator=torch.Generator().manual_seed(2))
    out = SAMPLERS[name](inpainted(D, known, mask), z_t, sigmas, generator=torch.Generator().manual_seed(2))
    on = mask.expand_as(known).bool()
    assert torch.allclose(out[on], known[on], atol=1e-5)
    assert torch.equal(out[1], free[1])              # an example without a mask is untouched


def test_pinned_latent_footprint():
    gen = ScenarioGenerator.load()
    toks = [[{**CAR, "speed": 6.0}], [CAR], None, np.zeros((0, 170), np.float32)]
    z, mask = pinned_latent(gen.ae, toks, gen.latent_scale)
    cells = mask.sum(dim=(1, 2, 3))
    assert 1 <= cells[0] <= 8 and cells[1:].sum() == 0     # 6.25 m cells: a car owns a few
    assert pinned_latent(gen.ae, toks[1:], gen.latent_scale) is None


def car_and_truck_tokens(net):
    """A window of city.net.xml and two pinnable tokens on its lanes: a car stopping (6 -> 1 m/s)
    and a slow truck (9 m, 2 m/s)."""
    xy, yaw = net.random_road_points(400, np.random.default_rng(0))
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    i, j = map(int, np.argwhere((d > 15) & (d < 40))[0])
    centre = (xy[i] + xy[j]) / 2
    window = [Window(float(centre[0]), float(centre[1]), 0.0)]   # yaw 0: scene frame = world - centre
    toks = [{"x": float(xy[k, 0] - centre[0]), "y": float(xy[k, 1] - centre[1]), "heading": float(yaw[k]),
             **size} for k, size in ((i, {"length": 4.6, "width": 1.8, "speed": 6.0, "final_speed": 1.0}),
                                     (j, {"length": 9.0, "width": 2.5, "speed": 2.0}))]
    return window, toks


def nearest(scene, tok) -> tuple[int, float]:
    d = np.hypot(scene.boxes[:, 0] - tok["x"], scene.boxes[:, 1] - tok["y"])
    return int(d.argmin()), float(d.min())


def test_shipped_model_places_a_pinned_token_exactly():
    net = Network.load("networks/city.net.xml")
    gen = ScenarioGenerator.load()
    window, toks = car_and_truck_tokens(net)
    pinned = gen.generate(net, window, tokens=[toks], p_mask=0.5, seed=3)
    again = gen.generate(net, window, tokens=[toks], p_mask=0.5, seed=3)
    assert np.array_equal(pinned[0].boxes, again[0].boxes)
    s = pinned[0]
    for t in toks:
        k, d = nearest(s, t)
        # the token-match rule (2.2 m, 0.2 rad); measured here 1.18 m / 0.03 rad and 0.28 m / 0.02 rad
        assert d < 2.2 and abs(np.angle(np.exp(1j * (s.boxes[k, 2] - t["heading"])))) < 0.2
        # the decoder draws the 9 m truck between about 7.4 and 11 m over seeds
        assert abs(s.boxes[k, 3] - t["length"]) < 2.5
    k, _ = nearest(s, toks[0])
    # the car asks 6 -> 1 m/s, a deceleration the decoder never draws: it moves along its decoded
    # path at the token's speeds (pace_to_pins; lane snap may shorten a step by centimetres)
    assert s.speed[k, T0] == pytest.approx(6.0, abs=0.1) and s.speed[k, -1] == pytest.approx(1.0, abs=0.1)
    k, _ = nearest(s, toks[1])
    assert s.speed[k, T0] == pytest.approx(2.0, abs=0.1)
    drawn = gen.generate(net, window, tokens=[toks], p_mask=0.5, seed=3,
                         config=replace(gen.config, pin_speeds=False))[0]
    assert np.array_equal(drawn.boxes, s.boxes)                    # pacing moves no box
    k, _ = nearest(drawn, toks[0])
    # as the decoder draws it, reading the token; a decoder without the tokens drew the final speed
    # at 4.8-6.1 m/s
    assert abs(drawn.speed[k, T0] - toks[0]["speed"]) < 2.0 and drawn.speed[k, -1] < 4.0
    free = gen.generate(net, window, tokens=[toks], p_mask=0.5, seed=3,
                        config=replace(gen.config, pin_tokens=False))
    assert not np.array_equal(free[0].boxes, s.boxes)


def test_a_pinned_turn_the_road_does_not_make_keeps_the_tokens_speeds():
    """Asked to turn where no lane turns, the agent is straightened by lane snap onto its lane, and
    re-timed along the snapped path: its speeds stay the token's (before the second pacing they read
    6.66 and 4.92 m/s at +1 / +2 s for 6 asked)."""
    net = Network.load("networks/city.net.xml")
    gen = ScenarioGenerator.load()
    window, toks = car_and_truck_tokens(net)
    car = dict(toks[0], final_speed=6.0, heading_to_final=0.4)
    s = gen.generate(net, window, tokens=[[car, toks[1]]], p_mask=0.5, seed=3)[0]
    k, _ = nearest(s, car)
    assert np.allclose(s.speed[k], 6.0, atol=0.1)
    free = gen.generate(net, window, tokens=[[car, toks[1]]], p_mask=0.5, seed=3,
                        config=replace(gen.config, lane_snap=False))[0]
    k, _ = nearest(free, car)
    assert free.traj[k, -1, 2] - free.traj[k, T0, 2] == pytest.approx(0.8, abs=0.01)  # the token's turn


def test_shipped_model_keeps_a_slow_truck_moving():
    """A slow long vehicle is generated moving at the decoder's own speeds, with pin calibration
    and without (by default it moves at the token's: test_shipped_model_places_a_pinned_token_exactly).
    The decoder draws the 2 m/s truck still moving, slowly; calibration slows it further
    (docs/evaluation.md, "Token control")."""
    net = Network.load("networks/city.net.xml")
    gen = ScenarioGenerator.load()
    window, toks = car_and_truck_tokens(net)
    drawn = replace(gen.config, pin_speeds=False)                  # the decoder's own speeds
    for config in (drawn, replace(drawn, pin_calibration=False)):
        s = gen.generate(net, window, tokens=[toks], p_mask=0.5, seed=3, config=config)[0]
        k, _ = nearest(s, toks[1])
        assert 0.3 < s.speed[k, T0] < toks[1]["speed"] + 1.5


def test_turn_to_pins_turns_the_matched_agent_rigidly_about_its_pose():
    boxes = np.array([[0.0, 0.0, 0.3, 4.5, 1.8], [20.0, 0.0, 0.0, 4.5, 1.8]])
    t = np.arange(-2, 3, dtype=np.float64)
    traj = np.zeros((2, 5, 3))
    traj[0, :, 0], traj[0, :, 1], traj[0, :, 2] = 10 * t * np.cos(0.3), 10 * t * np.sin(0.3), 0.3
    traj[1, :, 0] = 20.0
    pins = np.array([[0.6, 0.4, 1.0],       # 0.7 m from the first agent, heading 1.0 rad
                     [30.0, 0.0, 2.0]])     # 10 m from either: no agent of its own
    b, tr, turned = turn_to_pins(boxes, traj, pins, radius=2.0)
    assert turned.tolist() == [True, False]
    assert np.allclose(tr[0, :, 2], 1.0) and b[0, 2] == pytest.approx(1.0)
    assert np.allclose(tr[0, :, :2], np.c_[10 * t * np.cos(1.0), 10 * t * np.sin(1.0)])   # same steps
    assert np.array_equal(b[1], boxes[1]) and np.array_equal(tr[1], traj[1])
    assert np.allclose(b[0, [0, 1, 3, 4]], boxes[0, [0, 1, 3, 4]])       # position and size stay
    two = turn_to_pins(boxes[:1], traj[:1], np.array([[0.5, 0.0, 1.0], [0.1, 0.0, -1.0]]), 2.0)
    assert two[0][0, 2] == pytest.approx(-1.0)                          # one agent, the nearer pin


def test_pace_to_pins_moves_the_agent_along_its_path_at_the_tokens_speeds():
    t = np.arange(-2, 3, dtype=np.float64)
    boxes = np.array([[0.0, 0.0, 0.0, 4.5, 1.8], [30.0, 0.0, 0.0, 4.5, 1.8]])
    traj = np.zeros((2, 5, 3))
    traj[0, :, 0] = 8.0 * t                                        # decoded at 8 m/s along +x
    traj[1, :, 0] = 30.0
    ones = np.ones((1, 5), bool)
    pins = np.array([[0.5, 0.0, 0.0, 10.0, 4.0],                   # 10 -> 4 m/s
                     [60.0, 0.0, 0.0, 5.0, np.nan]])               # no agent within 2 m
    tr, paced = pace_to_pins(boxes, traj, pins, 2.0)
    assert paced.tolist() == [True, False] and np.array_equal(tr[1], traj[1])
    v = speeds_from_traj(tr[:1], ones)[0]
    # SUMO's 1-s update at -3 m/s^2: v(-1) 13, v(0) 10, v(+1) 7, v(+2) 4 (t = -2 extrapolated: 16)
    assert np.allclose(v, [16.0, 13.0, 10.0, 7.0, 4.0])
    assert np.allclose(tr[0, :, 1], 0.0) and np.allclose(tr[0, :, 2], 0.0)   # on its path
    assert np.array_equal(tr[0, T0], traj[0, T0])                           # the current pose stays
    # no final speed given: the decoded change of speed is kept (8 -> 8 decoded: 5 -> 5)
    tr, _ = pace_to_pins(boxes[:1], traj[:1], np.array([[0.0, 0.0, 0.0, 5.0, np.nan]]), 2.0)
    assert np.allclose(speeds_from_traj(tr, ones)[0], 5.0)
    # a standing token: every pose at the current one
    tr, _ = pace_to_pins(boxes[:1], traj[:1], np.array([[0.0, 0.0, 0.0, 0.0, 0.0]]), 2.0)
    assert np.allclose(tr[0], traj[0, T0])


def test_retime_follows_a_turn_and_goes_on_straight_beyond_it():
    # a quarter circle of radius 10 m from (0, 0) heading +x to (10, 10) heading +y, 1-s poses
    a = np.linspace(-np.pi / 4, np.pi / 2, 5)
    path = np.c_[10 * np.sin(a), 10 - 10 * np.cos(a), a]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1))]
    arc -= arc[T0]
    out = retime(path, arc)                                        # the same arc lengths: the same poses
    assert np.allclose(out, path)
    out = retime(path, np.array([arc[0] - 30.0, arc[1] / 2, 0.0, arc[-1] + 5.0, arc[-1] + 10.0]))
    assert np.allclose(out[T0], path[T0])
    assert np.allclose(out[1, :2], (path[1, :2] + path[T0, :2]) / 2)   # halfway along the chord
    assert np.allclose(out[3:, :2], path[-1, :2] + np.outer([5.0, 10.0], [0.0, 1.0]))  # on along +y
    back = path[0, :2] - 30.0 * np.array([np.cos(a[0]), np.sin(a[0])])
    assert np.allclose(out[0, :2], back) and out[0, 2] == pytest.approx(a[0])


def test_pinned_poses_carry_the_tokens_speeds():
    toks = [{**CAR, "speed": 8.0, "final_speed": 3.0, "heading_to_final": 0.2}, {**CAR, "speed": 2.0},
            {"x": 1.0, "y": 2.0}]
    p = pinned_poses(toks)
    assert p.shape == (2, 6) and p[0, 3:].tolist() == [8.0, 3.0, 0.2]
    assert p[1, 3] == 2.0 and np.isnan(p[1, 4:]).all()
    assert pinned_poses(None).shape == (0, 6)


def test_pace_to_pins_turns_the_future_as_the_token_asks():
    """The decoder draws the future from the map and ignores a token's turn; a pinned token that
    gives ``heading_to_final`` gets its arc from the agent's current pose (the past stays the
    decoded path's, re-timed), as the pin was drawn (token_trajectories)."""
    t = np.arange(-2, 3, dtype=np.float64)
    boxes = np.array([[0.0, 0.0, 0.0, 4.5, 1.8]])
    traj = np.zeros((1, 5, 3))
    traj[0, :, 0] = 8.0 * t                                        # decoded straight on at 8 m/s
    tok = {"x": 0.0, "y": 0.0, "heading": 0.0, "length": 4.5, "width": 1.8, "speed": 10.0,
           "final_speed": 10.0, "heading_to_final": 0.3}
    tr, paced = pace_to_pins(boxes, traj, pinned_poses([tok]), 2.0)
    want = token_trajectories([tok])[1][0]
    assert paced.all() and np.allclose(tr[0, T0:], want[T0:])       # the token's left turn
    assert tr[0, -1, 2] == pytest.approx(0.6) and tr[0, -1, 1] > 3.0
    assert np.allclose(tr[0, :T0, 1], 0.0) and np.allclose(tr[0, :T0, 0], [-20.0, -10.0])


def test_a_pinned_agent_on_a_junction_takes_the_tokens_lane(cross_net):
    """Inside a junction the decoder's heading is its least certain output; a pinned token states
    it, and the agent ends on the lane that heading follows, not on a nearer crossing one."""
    from sumo_scendiff.generation.lane_snap import snap_to_lanes
    net = Network.load(cross_net)
    window = Window(0.0, 0.0, 0.0)
    lane = next(i for i, ln in enumerate(net.lanes) if ln.internal and ln.car
                and ln.shape[-1][1] - ln.shape[0][1] > 10 and abs(ln.shape[-1][0] - ln.shape[0][0]) < 0.5)
    xy = np.asarray(net.lines[lane].interpolate(0.5, normalized=True).coords[0])   # northbound, mid-junction
    token = {"x": float(xy[0]) + 0.5, "y": float(xy[1]), "heading": np.pi / 2, "length": 4.5,
             "width": 1.8, "speed": 5.0}
    decoded_yaw = 0.2                                    # the decoder says east, along the crossing lane
    boxes = np.array([[xy[0] + 0.5, xy[1], decoded_yaw, 4.5, 1.8]], np.float32)
    traj = np.repeat(boxes[:, None, :3], 5, 1)
    scene = build_scene(window, np.array([0.9], np.float32), boxes, traj, GenerationConfig(), net,
                        pins=pinned_poses([token]))
    assert len(scene) == 1 and scene.boxes[0, 2] == pytest.approx(np.pi / 2, abs=0.02)
    assert abs(scene.boxes[0, 0] - xy[0]) < 1e-2                   # on the northbound lane's centre line
    unpinned = snap_to_lanes(boxes, traj, window, net)[0]
    assert abs(unpinned[0, 2] - np.pi / 2) > 0.5                   # as decoded: the eastbound lane


def test_calibrated_pins_draw_what_the_decoder_turns_into_the_token():
    """The decoder pulls a pinned agent toward the typical (a 9 m truck drawn at 2 m/s decodes
    faster); calibrated_pins draws it so that the decoding is
    nearer what the token asks, in speed and length, and leaves position, heading and width as asked."""
    import torch

    from sumo_scendiff.generation.pinning import (
        _decode_pins,
        _encode,
        _footprint,
        calibrated_pins,
    )
    from sumo_scendiff.map.raster import render_map
    net = Network.load("networks/city.net.xml")
    gen = ScenarioGenerator.load()
    window, toks = car_and_truck_tokens(net)
    m = torch.from_numpy(render_map(net, window[0])[None])
    asked = [[dict(toks[1])]]                                    # the truck: 9 m, 2 m/s
    with torch.no_grad():
        drawn = calibrated_pins(gen.ae, m, asked)

        def decoded(pins):
            mu, empty = _encode(gen.ae, pins, gen.raster)
            z = torch.lerp(empty.expand_as(mu), mu, _footprint(mu, empty, 1.0))
            return _decode_pins(gen.ae, z, m, pins, 100.0)[0, 0]
        before, after = decoded(asked), decoded(drawn)
    want = np.array([2.0, 2.0, 9.0])
    assert np.abs(after - want).sum() < np.abs(before - want).sum() - 1.0
    assert abs(after[0] - 2.0) < 1.0 and abs(after[0] - 2.0) < abs(before[0] - 2.0)
    assert all(drawn[0][0][f] == toks[1][f] for f in ("x", "y", "heading", "width"))
