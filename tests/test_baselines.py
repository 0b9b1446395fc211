"""Tests of the baselines (sumo_scendiff/baselines.py): Random Log Selection and lane-uniform insertion."""
from __future__ import annotations

import numpy as np
import pytest
import shapely

from sumo_scendiff.core.geometry import T0, TIMES, Window, box_corners, wrap_angle
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.evaluate.baselines import (
    DENSITY_PER_KM_LANE,
    TYPE_LENGTH,
    TYPE_VCLASS,
    LanePath,
    LaneUniform,
    RandomLogSelection,
)

CENTRE = Window(100.0, 100.0, 0.3, 100.0)


def pool(n_scenes: int = 12) -> list[Scene]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(n_scenes):
        n = i % 5
        xy = rng.uniform(-45, 45, (n, 2))
        yaw = rng.uniform(-3, 3, n)
        traj = np.repeat(np.column_stack([xy, yaw])[:, None], 5, 1)
        out.append(Scene(Window(1e4 * i, -5e3, rng.uniform(-3, 3), 100.0),
                         np.column_stack([xy, yaw, np.full(n, 4.6), np.full(n, 1.8)]), traj,
                         np.ones((n, 5), bool), rng.uniform(0, 10, (n, 5)), np.zeros(n), net=f"pool{i}"))
    return out


def same(a: Scene, b: Scene) -> bool:
    return len(a) == len(b) and all(np.array_equal(getattr(a, k), getattr(b, k))
                                    for k in ("boxes", "traj", "traj_mask", "speed", "vclass"))


# ---- Random Log Selection ----------------------------------------------------------------------
def test_random_log_copies_a_pool_scene_unchanged():
    p = pool()
    s = RandomLogSelection(p, seed=1).generate(CENTRE)
    src = p[s.meta["source"]]
    assert s.window == CENTRE
    assert same(s, src)  # same scene-frame arrays, now in the target window


def test_random_log_deterministic_for_seed():
    p = pool()
    a, b = RandomLogSelection(p, seed=7), RandomLogSelection(p, seed=7)
    seq_a = [a.generate(CENTRE).meta["source"] for _ in range(10)]
    seq_b = [b.generate(CENTRE).meta["source"] for _ in range(10)]
    assert seq_a == seq_b
    assert [a.generate(CENTRE, index=i).meta["source"] for i in range(10)] == \
        [b.generate(CENTRE, index=i).meta["source"] for i in range(10)]
    c = RandomLogSelection(p, seed=8)
    assert [c.generate(CENTRE, index=i).meta["source"] for i in range(10)] != \
        [a.generate(CENTRE, index=i).meta["source"] for i in range(10)]


def test_random_log_told_count_and_smaller_window():
    p = pool()
    rl = RandomLogSelection(p, seed=2)
    for n in range(5):
        assert len(rl.generate(CENTRE, n=n)) == n
    assert len(rl.generate(CENTRE, n=40)) == 4  # closest available count
    small = Window(0.0, 0.0, 0.0, 20.0)
    s = rl.generate(small)
    assert small.contains(s.boxes[:, :2]).all()
    with pytest.raises(ValueError):
        RandomLogSelection([], seed=0)


# ---- LaneUniform -------------------------------------------------------------------------------
def world_polys(s: Scene):
    b = s.boxes.astype(float)
    xy = s.window.scene_to_world(b[:, :2])
    return shapely.polygons(box_corners(xy[:, 0], xy[:, 1], s.window.yaw_to_world(b[:, 2]), b[:, 3], b[:, 4]))


def test_lane_uniform_no_overlap_inside_window_told_count(grid):
    lu = LaneUniform(grid, seed=0)
    for i in range(10):
        s = lu.generate(CENTRE, n=15, index=i)
        assert len(s) == 15 and s.meta["placed"] == 15
        assert CENTRE.contains(s.boxes[:, :2]).all()
        polys = world_polys(s)
        tree = shapely.STRtree(polys)
        a, b = tree.query(polys, predicate="intersects")
        assert np.all(a == b), "overlapping boxes"
        assert s.traj_mask.all()
    assert len(lu.generate(CENTRE, n=0)) == 0


def test_lane_uniform_deterministic(grid):
    a, b = LaneUniform(grid, seed=3), LaneUniform(grid, seed=3)
    assert all(same(a.generate(CENTRE), b.generate(CENTRE)) for _ in range(3))
    assert same(a.generate(CENTRE, index=5), b.generate(CENTRE, index=5))
    assert not same(LaneUniform(grid, seed=4).generate(CENTRE, n=5, index=0),
                    a.generate(CENTRE, n=5, index=0))


def test_lane_uniform_on_normal_lanes_with_lane_heading_and_speed(grid):
    s = LaneUniform(grid, seed=1).generate(CENTRE, n=20, index=0)
    for ag in s.world_agents():
        pt = shapely.Point(ag["x"], ag["y"])
        on = [grid.lanes[i] for i in grid.lane_tree.query(pt, predicate="dwithin", distance=0.01)
              if grid.lines[i].distance(pt) < 1e-3 and grid.lanes[i].car]
        normal = [ln for ln in on if not ln.internal]
        assert len(normal) == 1  # on exactly one normal lane's centre line (straight grid lanes)
        ln = normal[0]
        head = np.arctan2(*(ln.shape[-1] - ln.shape[0])[::-1])
        assert abs(wrap_angle(ag["heading"] - head)) < 1e-4
        assert 0.2 * ln.speed <= ag["speed"] <= 2.0 * ln.speed
    assert set(s.vclass.tolist()) <= set(TYPE_VCLASS.tolist())
    assert np.isclose(s.boxes[:, 3, None], TYPE_LENGTH[None]).any(1).all()
    # constant-speed motion along the centre line: 1 s apart = speed metres apart (straight grid lanes)
    step = np.linalg.norm(np.diff(s.traj[:, :, :2], axis=1), axis=-1)
    assert np.allclose(step, s.speed[:, :4], atol=1e-3)
    assert np.allclose(s.traj[:, T0], s.boxes[:, :3])


def test_lane_uniform_own_count_rule(grid):
    lu = LaneUniform(grid, seed=2)
    counts = [len(lu.generate(CENTRE, index=i)) for i in range(60)]
    lane_km = lu.generate(CENTRE, n=0).meta["lane_km"]
    assert 0.3 < lane_km < 1.0  # 12 directional lanes cross the middle 100 m square
    assert np.mean(counts) == pytest.approx(lane_km * DENSITY_PER_KM_LANE, rel=0.25)
    assert len(LaneUniform(grid, count_rule=lambda km, rng: 4, seed=0).generate(CENTRE)) == 4
    assert len(lu.generate(Window(5000.0, 5000.0))) == 0  # no road


def test_lane_path_extends_straight_past_the_ends():
    path = LanePath(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]))
    xy, yaw = path.pose(np.array([-5.0, 5.0, 15.0, 25.0]))
    assert np.allclose(xy, [[-5, 0], [5, 0], [10, 5], [10, 15]])
    assert np.allclose(wrap_angle(yaw), [0, 0, np.pi / 2, np.pi / 2])
    assert len(TIMES) == 5
