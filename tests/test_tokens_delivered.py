"""Delivered tokens (generation/deliver.py, token_resolve.py): what a partial token gives is what
the generated scene, and SUMO, get. Real shipped model on networks/city.net.xml, small scale."""
import logging
from dataclasses import replace

import numpy as np
import pytest

from sumo_scendiff.core.geometry import T0, Window, wrap_angle
from sumo_scendiff.generation.deliver import delivered_rows, place_rows
from sumo_scendiff.generation.token_resolve import resolve_tokens
from sumo_scendiff.map.network import Network
from sumo_scendiff.tokens.file import TokenFileError, parse_tokens

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"


def road_window(net) -> Window:
    """A window centred 50 m along the first long straight lane, its axis along the lane: a token
    at (0, 0) heading 0 drives along it."""
    for i in net.car_lane_ids:
        ln = net.lanes[i]
        if not ln.internal and ln.length >= 120 and np.ptp(ln.seg_yaw) < 0.01:
            xy, h = net.lane_pose(i, 50.0)
            return Window(float(xy[0]), float(xy[1]), float(h))
    raise AssertionError("no straight lane")


def delivered(scene, token_index: int = 0) -> int:
    return scene.meta["delivers"].index(token_index)


def test_a_partial_speed_token_is_delivered(city, gen):
    w = road_window(city)
    tok = {"x": 0.0, "y": 0.0, "speed": 12.0}
    s = gen.generate(city, [w], tokens=[[tok]], p_mask=0.5, seed=0)[0]
    k = delivered(s)
    assert np.hypot(*s.boxes[k, :2]) < 2.0
    assert s.speed[k, T0] == pytest.approx(12.0, abs=0.3)
    drawn = gen.generate(city, [w], tokens=[[tok]], p_mask=0.5, seed=0,
                         config=replace(gen.config, deliver_tokens=False))[0]
    assert "delivers" not in drawn.meta


def test_a_token_drawn_without_delivery_is_never_trimmed_to_a_count(city, gen):
    # density 0: the window keeps no vehicle of the model's own, but the one the token asked for
    w = road_window(city)
    s = gen.generate(city, [w], tokens=[[{"x": 0.0, "y": 0.0, "speed": 12.0}]], p_mask=0.5, seed=0,
                     density=0.0, config=replace(gen.config, deliver_tokens=False))[0]
    assert len(s.boxes) == 1 and np.hypot(*s.boxes[0, :2]) < 2.2


def test_a_stop_token_stops_and_pinned_tokens_are_untouched(city, gen):
    w = road_window(city)
    stop = parse_tokens({"agents": [{"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 8.0,
                                     "manoeuvre": "stop"}]}, "t.toml").agents[0]
    s = gen.generate(city, [w], tokens=[[stop]], p_mask=0.5, seed=1)[0]
    k = delivered(s)
    assert s.speed[k, T0] == pytest.approx(8.0, abs=0.3) and s.speed[k, -1] == pytest.approx(0.0, abs=0.1)
    # a pinnable token has its own path: delivery leaves the scene byte-identical
    pin = dict(stop, length=4.6, width=1.8)
    on = gen.generate(city, [w], tokens=[[pin]], p_mask=0.5, seed=1)[0]
    off = gen.generate(city, [w], tokens=[[pin]], p_mask=0.5, seed=1,
                       config=replace(gen.config, deliver_tokens=False))[0]
    assert np.array_equal(on.boxes, off.boxes) and np.array_equal(on.traj, off.traj) and on.meta == off.meta


def test_an_unmatched_token_is_placed_on_its_lane(city, gen):
    w = road_window(city)
    nothing = replace(gen.config, threshold=1.0)          # the model generates no agent at all
    toks = [{"x": 20.3, "y": 0.4, "speed": 5.0}, {"x": -15.0, "y": 0.0, "length": 10.5, "width": 2.5}]
    s = gen.generate(city, [w], tokens=[toks], p_mask=0.5, seed=0, config=nothing)[0]
    assert s.meta["delivers"] == [0, 1] and s.meta["cell"] == [-1, -1]
    lane, _, lateral, _ = city.lookup(*w.scene_to_world(s.boxes[0, :2][None])[0])
    assert lateral < 0.05 and abs(s.boxes[0, 1]) < 0.05              # on the centre line
    assert s.boxes[0, 2] == pytest.approx(0.0, abs=0.01)             # the lane's heading
    assert s.boxes[0, 3:].tolist() == pytest.approx([4.6, 1.8])      # a typical car
    assert np.allclose(s.speed[0], 5.0, atol=0.05)
    assert s.boxes[1, 3:].tolist() == pytest.approx([10.5, 2.5])
    # no speed: the lane's
    assert s.speed[1, T0] == pytest.approx(city.lanes[city.lane_index[lane.id]].speed, abs=0.05)


def test_a_pinned_truck_the_model_does_not_draw_is_placed_on_its_lane(city, gen):
    """A pinned token (pose, size, speed) whose agent the decoder does not find, here a truck 0.77 m
    off its lane's centre line with nothing drawn at all, is placed on that lane like a partial token
    no agent matched: before, it vanished without a warning."""
    w = road_window(city)
    truck = {"x": 10.0, "y": 0.77, "heading": 0.0, "length": 11.0, "width": 2.5, "speed": 8.0}
    s = gen.generate(city, [w], tokens=[[truck]], p_mask=0.5, seed=0, config=replace(gen.config, threshold=1.0))[0]
    assert s.meta["delivers"] == [0] and s.meta["cell"] == [-1] and "token_warnings" not in s.meta
    assert s.boxes[0].tolist() == pytest.approx([10.0, 0.0, 0.0, 11.0, 2.5], abs=0.05)   # on the centre line
    assert s.speed[0, T0] == pytest.approx(8.0, abs=0.05)


def test_an_off_road_token_is_a_warning_not_a_silent_drop(city, gen, caplog):
    w = road_window(city)
    g = np.stack(np.meshgrid(np.arange(-45, 46, 5.0), np.arange(-45, 46, 5.0)), -1).reshape(-1, 2)
    off = g[city.match_poses(w.scene_to_world(g), radius=4.0).lane < 0][0]
    tok = {"x": float(off[0]), "y": float(off[1]), "speed": 5.0}
    with caplog.at_level(logging.WARNING, logger="sumo_scendiff.generation.deliver"):
        s = gen.generate(city, [w], tokens=[[tok]], p_mask=0.5, seed=0,
                         config=replace(gen.config, threshold=1.0))[0]
    assert len(s) == 0
    assert len(s.meta["token_warnings"]) == 1 and "token 0 at" in s.meta["token_warnings"][0]
    assert "not placed" in caplog.text


def test_a_placed_token_wins_over_a_generated_agent_it_overlaps(city):
    w = road_window(city)
    boxes = np.array([[3.0, 0.0, 0.0, 4.6, 1.8], [-30.0, 0.0, 0.0, 4.6, 1.8]])
    traj = np.repeat(boxes[:, None, :3], 5, axis=1)
    rows = delivered_rows([{"x": 0.0, "y": 0.0, "speed": 0.0}, {"x": 0.5, "y": 0.0}])
    b, _, owner, gone, lines = place_rows(boxes, traj, np.array([-1, -1]), rows, w, city)
    assert gone == [0] and owner.tolist() == [-1, 0]            # the generated car gave way
    assert b[0, 0] == -30.0 and abs(b[1, 0]) < 0.1
    assert len(lines) == 1 and lines[0].startswith("token 1 at") and "token 0" in lines[0]


def test_network_references_resolve_to_poses(diagonal_net):
    net = Network.load(diagonal_net)
    right, left = (net.lanes[net.lane_index[f"ab_{i}"]] for i in (0, 1))
    xy, _ = net.lane_pose(net.lane_index[right.id], 200.0)
    w = Window(float(xy[0]), float(xy[1]), np.pi / 4)                # the ego on the right lane
    spec = parse_tokens({"agents": [{"ahead": 10, "speed": 5}, {"ahead": 10, "lane_offset": 1},
                                    {"edge": "ab", "lane": 1, "pos": 200.0}]}, "t.toml")
    a, b, c = resolve_tokens(net, w, spec.for_window(w))
    lat = [net.lookup(*w.scene_to_world(np.array([[t["x"], t["y"]]]))[0]) for t in (a, b, c)]
    # lane 0 is the right-hand lane, lane_offset +1 the one to its left
    assert [m[0].id for m in lat] == [right.id, left.id, left.id] and max(m[2] for m in lat) < 0.01
    assert a["x"] == pytest.approx(10.0, abs=0.1) and abs(a["y"]) < 0.01 and b["y"] > 2.5
    assert c["x"] == pytest.approx(0.0, abs=0.1) and c["y"] == pytest.approx(b["y"], abs=0.01) and c["heading"] == pytest.approx(0.0, abs=1e-3)
    assert "ahead" not in a and a["speed"] == 5.0
    for agent, msg in (({"edge": "zz", "pos": 1}, r"token 0: edge: no edge 'zz'"),
                       ({"edge": "ab", "lane": 2, "pos": 1}, r"edge 'ab' has no lane 2 \(lanes 0\.\.1\)"),
                       ({"edge": "ab", "pos": 900}, r"token 0: pos: 900 m is not on lane"),
                       ({"ahead": 10, "lane_offset": -1}, r"token 0: lane_offset: edge 'ab' has no lane -1"),
                       ({"edge": "ab", "pos": 10}, r"outside the window"),
                       ({"ahead": 10, "yaw": np.pi}, r"token 0: ahead: no car lane along the window's heading")):
        # a window turned against the one-way road has no lane along its axis
        v = Window(w.cx, w.cy, w.yaw + agent.pop("yaw", 0.0))
        with pytest.raises(TokenFileError, match=msg):
            resolve_tokens(net, v, parse_tokens({"agents": [agent]}, "t.toml").for_window(v))


def test_a_stopping_token_stands_in_sumo_after_the_replayed_future(city, gen):
    """End to end: the partial token (x, y, heading, speed 8, manoeuvre "stop") seeded into SUMO
    and held on its generated future for 2 s stands then, delivered and as the model alone draws it
    (delivery off: the decoder's gate toward the token's speeds; a decoder without it left it moving)."""
    from sumo_scendiff.sim.cosim import CoSimulation
    from sumo_scendiff.sim.sumo import SimConfig, start
    w = road_window(city)
    tok = parse_tokens({"agents": [{"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 8.0,
                                    "manoeuvre": "stop"}]}, "t.toml").agents[0]
    speeds = []
    for deliver in (True, False):
        scene = gen.generate(city, [w], tokens=[[tok]], p_mask=0.5, seed=1,
                             config=replace(gen.config, deliver_tokens=deliver))[0]
        sim = start(SimConfig(net="networks/city.net.xml"))
        try:
            cosim = CoSimulation(sim, city, generator=None)
            seeding = cosim.place(scene, [tok], ["user"], cosim.existing(w))
            sim.simulationStep()
            cosim.verify(seeding)
            k = seeding.token_of.index(0)
            vid = seeding.agent_ids[k]
            assert sim.vehicle.getSpeed(vid) == pytest.approx(8.0, abs=0.5) or not deliver
            cosim.replay_future(seeding, 2.0)
            speeds.append(sim.vehicle.getSpeed(vid))
        finally:
            sim.close()
    assert speeds[0] < 0.5 and speeds[1] < 0.5


def heading_to_final(traj) -> float:
    d = traj[-1, :2] - traj[T0, :2]
    return float(np.arctan2(d[1], d[0]) - traj[T0, 2])


def test_a_stated_pose_no_lane_runs_along_is_kept_as_stated(city, gen):
    """A vehicle half through a turn (its centre off every lane's centre line, its heading between
    the lanes'): the token's position and heading are what the scene gets, not the nearest lane's.
    A heading a lane follows still puts the vehicle on that lane's centre line."""
    w = road_window(city)
    askew = {"x": 0.0, "y": 0.8, "heading": 0.5, "speed": 8.0}
    along = {"x": 0.0, "y": 0.8, "heading": 0.1, "speed": 8.0}
    for tok in (askew, along):
        s = gen.generate(city, [w], tokens=[[tok]], p_mask=0.5, seed=0)[0]
        k = delivered(s)
        assert s.speed[k, T0] == pytest.approx(8.0, abs=0.3)
        if tok is askew:
            assert s.boxes[k, :3].tolist() == pytest.approx([0.0, 0.8, 0.5], abs=2e-3)
        else:
            assert abs(s.boxes[k, 1]) < 0.05 and abs(s.boxes[k, 2]) < 0.01   # on the lane, its heading


def test_a_turn_token_is_driven_where_the_lanes_let_it_and_named_where_not(city, gen):
    w = road_window(city)
    gentle = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 8.0, "heading_to_final": 0.05}
    s = gen.generate(city, [w], tokens=[[gentle]], p_mask=0.5, seed=0)[0]
    k = delivered(s)
    assert heading_to_final(s.traj[k].astype(float)) == pytest.approx(0.05, abs=0.01)
    assert "token_warnings" not in s.meta
    # a sharp left off a straight road: no lane turns so, the vehicle keeps to its lane, and says so
    sharp = dict(gentle, heading_to_final=0.6)
    s = gen.generate(city, [w], tokens=[[sharp]], p_mask=0.5, seed=0)[0]
    k = delivered(s)
    assert abs(heading_to_final(s.traj[k].astype(float))) < 0.1
    assert any("heading_to_final +0.60 rad: no car lane turns so" in line for line in s.meta["token_warnings"])


def test_a_placed_turn_token_at_a_standstill_moves(city, gen):
    """heading_to_final is defined only for a vehicle that moves (>= 0.5 m in 2 s): a token giving
    it with speed 0 and no final speed is a vehicle starting off, placed or matched."""
    w = road_window(city)
    tok = {"x": 10.0, "y": 0.0, "heading": 0.0, "speed": 0.0, "heading_to_final": 0.0}
    for threshold in (1.0, gen.config.threshold):      # placed (nothing generated), or matched
        s = gen.generate(city, [w], tokens=[[tok]], p_mask=0.5, seed=0,
                         config=replace(gen.config, threshold=threshold))[0]
        k = delivered(s)
        assert s.speed[k, T0] == pytest.approx(0.0, abs=0.05)
        assert np.hypot(*(s.traj[k, -1, :2] - s.traj[k, T0, :2])) >= 0.5


def test_a_turn_whose_drawn_final_speed_is_too_slow_for_it_is_still_driven(city):
    """turn_path with a final speed the token does not give tries lower final speeds first, then
    higher ones: a vehicle drawn slowing to 1 m/s cannot reach into the turn the token asks for by
    +2 s, one keeping its 8 m/s does. With the final speed given, only that one is tried."""
    from sumo_scendiff.generation.deliver import _direction, _scene_pose, turn_path
    from sumo_scendiff.generation.lane_snap import walk_lanes
    from sumo_scendiff.generation.pinning import _distance
    s = float(_distance(8.0, 0.0, np.asarray([2.0]))[0])
    for i in city.car_lane_ids:
        ln = city.lanes[i]
        if ln.internal or ln.length < s + 5:
            continue
        xy, h = city.lane_pose(i, ln.length - 8.0)
        w = Window(float(xy[0]), float(xy[1]), float(h))
        pose = _scene_pose(city, w, i, ln.length - 8.0)
        turns = [(lane, p) for lane, p in walk_lanes(city, i, ln.length - 8.0, s)
                 if abs(_direction(pose, _scene_pose(city, w, lane, p))) > 0.3]
        if turns:
            alpha = _direction(pose, _scene_pose(city, w, *turns[0]))
            break
    else:
        raise AssertionError("no lane ending in a turn")
    found = turn_path(city, w, pose, 8.0, 1.0, alpha, free=True)
    assert found is not None and found[1] > 1.0
    path, _ = found
    assert abs(wrap_angle(np.arctan2(*(path[-1, 1::-1] - path[T0, 1::-1])) - pose[2] - alpha)) <= 0.1
    assert turn_path(city, w, pose, 8.0, 1.0, alpha, free=False) is None


def test_the_models_own_drawing_follows_a_partial_tokens_final_speed(city, gen):
    """No delivery, no pinning: the vehicle the model draws under a token (x, y, heading, speed 8)
    is the token's, and its speed at +2 s follows the token's final speed, 0 or 12 m/s (the decoder
    reads the tokens; one that did not drew a stop still moving at +2 s)."""
    w = road_window(city)
    own = replace(gen.config, deliver_tokens=False, pin_tokens=False)
    for seed in (0, 1):
        drawn = {}
        for final in (0.0, 12.0):
            tok = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 8.0, "final_speed": final}
            s = gen.generate(city, [w], tokens=[[tok]], p_mask=0.5, seed=seed, config=own)[0]
            d = np.hypot(s.boxes[:, 0], s.boxes[:, 1])
            k = int(d.argmin())
            assert d[k] < 1.0 and abs(s.speed[k, T0] - 8.0) < 2.5
            drawn[final] = float(s.speed[k, -1])
        assert drawn[0.0] < 4.0 and drawn[12.0] > 9.0, drawn


def test_a_token_giving_one_of_its_speeds_is_drawn_at_it_without_braking_or_accelerating(city, gen):
    """No delivery, no pinning: a token giving its speed 8 m/s and nothing of its future, or its final
    speed alone, is drawn near it and at about a constant speed. A decoder that read the missing speed
    as 0 m/s drew the first braking and the second accelerating; the tokens' speeds are filled in
    (the decoder reads the one given as the other)."""
    w = road_window(city)
    own = replace(gen.config, deliver_tokens=False, pin_tokens=False)
    for seed in (0, 1, 2):
        for key, at in (("speed", T0), ("final_speed", -1)):
            s = gen.generate(city, [w], tokens=[[{"x": 0.0, "y": 0.0, "heading": 0.0, key: 8.0}]], p_mask=0.5,
                             seed=seed, config=own)[0]
            d = np.hypot(s.boxes[:, 0], s.boxes[:, 1])
            k = int(d.argmin())
            v = s.speed[k]
            assert d[k] < 1.0 and abs(v[at] - 8.0) < 2.5 and abs(v[-1] - v[T0]) < 2.0, (seed, key, v)


def test_a_lane_offset_inside_a_junction_is_counted_on_its_road(cross2_net):
    """A window centred on a junction (as ``run`` picks them): ``ahead`` finds an internal lane, one
    lane per connection; ``lane_offset = 1`` is counted on the road that lane leads from or to, and
    the error never names an internal lane the user did not write."""
    net = Network.load(cross2_net)
    y0 = float(net.lanes[net.lane_index["wc_0"]].shape[-1][1])
    w = Window(0.0, y0, 0.0)                                   # eastbound on its right lane, on the crossing
    inner = net.lookup(*w.scene_to_world(np.array([[2.0, 0.0]]))[0], 0.0, radius=5.0)[0]
    assert inner.internal                                      # what ahead = 2 finds
    (tok,) = resolve_tokens(net, w, parse_tokens({"agents": [{"ahead": 2, "lane_offset": 1}]}, "t.toml").for_window(w))
    lane = net.lookup(*w.scene_to_world(np.array([[tok["x"], tok["y"]]]))[0], 0.0)[0]
    assert lane.id in ("wc_1", "ce_1") and tok["heading"] == pytest.approx(0.0, abs=1e-3)
    far = parse_tokens({"agents": [{"ahead": 2, "lane_offset": 2, "speed": 3.0}]}, "t.toml").for_window(w)
    with pytest.raises(TokenFileError, match=r"token 0: lane_offset: edge 'wc' has no lane 2"):
        resolve_tokens(net, w, far)
    # run's windows: the road there has no such lane; one line naming the token, the token without its place
    said = []
    (tok,) = resolve_tokens(net, w, far, "t.toml", said)
    assert said == ["token 0: lane_offset: edge 'wc' has no lane 2 (lanes 0..1): not in this window; "
                    "the token is given without its place"]
    assert tok.get("x") is None and "ahead" not in tok and "lane_offset" not in tok and tok["speed"] == 3.0
