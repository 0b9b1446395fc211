"""A requested density delivered as a vehicle count: the most probable boxes kept to the count
(generator.trim_to_count), and the paper's infill where the model drew too few (generation/infill.py).
Real shipped model on networks/city.net.xml, small scale."""
from dataclasses import replace

import numpy as np
import pytest

from sumo_scendiff.core.geometry import TIMES, Window
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.generation.generator import trim_to_count
from sumo_scendiff.generation.infill import add_new_agents, scene_tokens


def test_trim_keeps_the_tokens_then_the_most_probable():
    prob = np.array([0.9, 0.3, 0.95, 0.1, 0.6])
    mine = np.array([True, False, True, True, True])     # agent 1 is a token's
    assert trim_to_count(prob, mine, 3).tolist() == [0, 1, 2]
    assert trim_to_count(prob, mine, 1).tolist() == [1]      # a token's vehicle is never trimmed
    assert trim_to_count(prob, mine, 9).tolist() == [0, 1, 2, 3, 4]


def test_trim_counts_only_the_agents_in_the_area():
    prob = np.array([0.9, 0.3, 0.95, 0.1, 0.6])
    mine = np.ones(5, bool)
    inside = np.array([True, True, False, True, True])       # agent 2 outside: kept, not counted
    assert trim_to_count(prob, mine, 2, None, inside).tolist() == [0, 2, 4]
    # agent 0 inside but not counted (its front in a junction): kept, being more probable than the
    # last that counts; agent 3, less probable, is not
    counted = np.array([False, True, False, True, True])
    assert trim_to_count(prob, mine, 2, counted, inside).tolist() == [0, 1, 2, 4]


def _scene(boxes, score) -> Scene:
    n = len(boxes)
    return Scene(Window(0.0, 0.0, 0.0), np.asarray(boxes, np.float32).reshape(n, 5),
                 np.zeros((n, len(TIMES), 3)), np.ones((n, len(TIMES)), bool), np.full((n, len(TIMES)), 5.0),
                 np.zeros(n), meta={"score": list(score), "cell": list(range(n))})


def test_infill_adds_only_new_clear_agents_most_probable_first():
    first = _scene([[0, 0, 0, 4.5, 1.8]], [0.9])
    second = _scene([[0.5, 0, 0, 4.5, 1.8],        # the first scene's agent redrawn: not new
                     [3.5, 0.0, 0, 4.5, 1.8],      # new centre, but its box overlaps the first's
                     [20, 0, 0, 4.5, 1.8], [40, 0, 0, 4.5, 1.8], [-30, 0, 0, 4.5, 1.8]],
                    [0.99, 0.9, 0.5, 0.8, 0.2])
    out = add_new_agents(first, second, 3, first.boxes[:, :2], 2.0)
    assert out.boxes[:, 0].tolist() == [0, 20, 40]
    assert out.meta["score"] == [0.9, 0.5, 0.8] and out.meta["infilled"] == 2
    assert add_new_agents(first, second, 1, first.boxes[:, :2], 2.0) is first
    # counted in an area (world frame; the window is at the origin): only agents there are added
    out = add_new_agents(first, second, 3, first.boxes[:, :2], 2.0, area=(-50.0, -50.0, 30.0, 50.0))
    assert out.boxes[:, 0].tolist() == [0, 20, -30]
    assert scene_tokens(first) == [{"x": 0.0, "y": 0.0, "heading": 0.0, "length": 4.5, "width": pytest.approx(1.8), "speed": 5.0}]


@pytest.mark.slow
def test_a_requested_density_is_the_windows_vehicle_count(city, gen):
    rng = np.random.default_rng(3)
    xy, yaw = city.random_road_points(24, rng)
    wins = [w for w in (Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw))
            if city.car_lane_km(w) > 0.3][:3]
    want = [int(np.round(20.0 * city.car_lane_km(w))) for w in wins]
    scenes = gen.generate(city, wins, seed=0, density=20.0)
    got = [len(s) for s in scenes]
    # the model alone, the density only a condition, draws its own count: above the request in
    # some windows, below in others
    own = [len(s) for s in gen.generate(city, wins, seed=0, density=20.0,
                                        config=replace(gen.config, match_density=False, infill_passes=0))]
    assert own != want
    for o, g, w in zip(own, got, want):
        assert g == w if o >= w else o <= g <= w      # trimmed to the count, or filled towards it
    assert sum(got) >= 0.75 * sum(want)
    # a count reached by infill keeps the first drawing's agents as they were
    first = gen.generate(city, wins, seed=0, density=20.0, config=replace(gen.config, infill_passes=0))
    for a, b in zip(first, scenes):
        np.testing.assert_array_equal(b.boxes[: len(a)], a.boxes)
    # the same seed, the same scenes, infill included, in batches of any size (to the generator's
    # mm rounding: a value on a rounding edge may land a mm either side, and two agents of equal
    # probability change places)
    small = gen.generate(city, wins[:2], seed=0, density=20.0, config=replace(gen.config, batch_size=1))
    for a, b in zip(small, scenes):
        a, b = (s.boxes[np.lexsort(np.round(s.boxes[:, :2], 1).T)] for s in (a, b))
        np.testing.assert_allclose(a[:, [0, 1, 3, 4]], b[:, [0, 1, 3, 4]], atol=1.5e-3)
        np.testing.assert_allclose(np.cos(a[:, 2] - b[:, 2]), 1.0, atol=1e-5)


def test_a_stochastic_sampler_draws_each_windows_noise_from_its_own_seed(gen, city):
    """With fresh noise at every step (euler-ancestral), a window's scene still depends on its seed
    alone: the same in a batch of one as beside other windows; the noise is the sampler's own."""
    xy, yaw = city.random_road_points(3, np.random.default_rng(4))
    wins = [Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw)]
    cfg = replace(gen.config, sampler="euler-ancestral", eta=1.0, infill_passes=0)
    many = gen.generate(city, wins, noise_seeds=[11, 12, 13], config=cfg)
    one = gen.generate(city, wins[1:2], noise_seeds=[12], config=replace(cfg, batch_size=1))
    np.testing.assert_allclose(one[0].boxes, many[1].boxes, atol=1.5e-3)
    ode = gen.generate(city, wins, noise_seeds=[11, 12, 13], config=replace(cfg, sampler="dpmpp-2m"))
    assert any(len(a) != len(b) or not np.allclose(a.boxes, b.boxes) for a, b in zip(many, ode))


def test_a_density_in_veh_per_km_counts_the_vehicles_on_edges_as_edgedata_does(city, gen):
    """With count_on_edges (a density asked in veh/km), the count is of the vehicles whose front is
    on a normal edge, as SUMO's edgeData density counts them; one nosing into a junction is kept
    beside it. Without it (a count of vehicles), every vehicle counts."""
    from sumo_scendiff.generation.infill import in_area
    rng = np.random.default_rng(5)
    xy, yaw = city.random_road_points(40, rng)
    wins = [w for w in (Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw))
            if city.car_lane_km(w) > 0.3][:4]
    want = [int(np.round(30.0 * city.car_lane_km(w))) for w in wins]
    edges = gen.generate(city, wins, seed=0, density=30.0, config=replace(gen.config, count_on_edges=True))
    every = gen.generate(city, wins, seed=0, density=30.0)
    on_edges = [int(in_area(s, None, city).sum()) for s in edges]
    assert sum(on_edges) >= 0.9 * sum(want) and all(g <= w for g, w in zip(on_edges, want))
    assert all(len(s) <= w for s, w in zip(every, want))
    # the windows hold vehicles inside junctions: beside the count with the rule, within it without
    assert sum(len(s) for s in edges) > sum(on_edges)
