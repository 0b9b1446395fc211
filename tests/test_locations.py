"""Window locations: user centres (``--center X,Y``) and automatically chosen busy, varied junctions."""
from __future__ import annotations

import itertools
import math
import os
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.map.locations import (
    KINDS,
    TLS_BONUS,
    Location,
    LocationError,
    auto_windows,
    candidates,
    parse_center,
    vehicles_in,
    window_at,
)
from sumo_scendiff.map.network import Network

from .conftest import netconvert

CITY = Path(__file__).resolve().parents[1] / "networks" / "city.net.xml"
COLOGNE8 = "/work/shared/nets/resco_cologne8/cologne8.net.xml"


@pytest.fixture(scope="module")
def city() -> Network:
    return Network.load(str(CITY))


@pytest.fixture(scope="module")
def cross(cross_net) -> Network:
    return Network.load(cross_net)


@pytest.fixture(scope="module")
def ramps(tmp_path_factory) -> Network:
    """On-ramp merge at m (2 + 1 lanes into 2), lane drop at b (2 -> 1), diverge at c (1 -> 1 + 1)."""
    nodes = ('<node id="a" x="0" y="0"/><node id="r" x="0" y="-60"/><node id="m" x="200" y="0"/>'
             '<node id="b" x="400" y="0"/><node id="c" x="600" y="0"/>'
             '<node id="e" x="800" y="0"/><node id="f" x="800" y="-80"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="{k}" speed="20"/>'
                    for a, b, k in (("a", "m", 2), ("r", "m", 1), ("m", "b", 2), ("b", "c", 1),
                                    ("c", "e", 1), ("c", "f", 1)))
    return Network.load(netconvert(nodes, edges, str(tmp_path_factory.mktemp("ramps") / "ramps.net.xml")))


def _centres(locs) -> np.ndarray:
    return np.array([(loc.window.cx, loc.window.cy) for loc in locs])


def _min_separation(locs) -> float:
    xy = _centres(locs)
    return min(float(np.hypot(*(p - q))) for p, q in itertools.combinations(xy, 2))


# ---- parse_center ------------------------------------------------------------------------------
@pytest.mark.parametrize("text, xy", [("1000,750", (1000.0, 750.0)), ("1000, 750", (1000.0, 750.0)),
                                      (" -12.5 ,3e2", (-12.5, 300.0))])
def test_parse_center_accepts_x_comma_y(text, xy):
    assert parse_center(text) == xy


@pytest.mark.parametrize("text", ["", "1000", "1000;750", "1000 750", "1,2,3", "a,b", ",5", "5,",
                                  "nan,1", "1,inf", "-inf,0"])
def test_parse_center_rejects_everything_else(text):
    with pytest.raises(LocationError) as e:
        parse_center(text)
    msg = str(e.value)
    assert msg == f"--center {text!r}: expected X,Y in network metres, e.g. --center 1000,750"
    assert "\n" not in msg


# ---- window_at ---------------------------------------------------------------------------------
def test_window_at_accepts_a_junction_centre(city):
    x, y = city.sumo_net.getNode("g10_2").getCoord()[:2]
    assert window_at(city, x, y) == Window(x, y, 0.0, 100.0)
    assert window_at(city, x, y, yaw=0.5, size=80.0) == Window(x, y, 0.5, 80.0)


def test_window_at_needs_a_car_lane_within_30_m(cross):
    # the two roads lie along the axes; their outer car-lane edges are 3.2 m off the axis
    assert window_at(cross, 25.0, 25.0) == Window(25.0, 25.0)   # 21.8 m from a car lane
    with pytest.raises(LocationError) as e:
        window_at(cross, 40.0, 40.0)                             # 36.8 m
    assert str(e.value) == ("--center 40,40: off the network cross.net.xml (nearest car lane 37 m away; "
                            "the network spans x -200..200, y -200..200)")


def test_window_at_rejects_a_far_point(city):
    with pytest.raises(LocationError) as e:
        window_at(city, 5000, 20)
    assert str(e.value) == ("--center 5000,20: off the network city.net.xml (nearest car lane 2999 m away; "
                            "the network spans x 0..2000, y 0..2000)")


@pytest.mark.parametrize("x, y", [(math.nan, 0.0), (0.0, math.inf), (-math.inf, math.nan)])
def test_window_at_rejects_non_finite_points(cross, x, y):
    with pytest.raises(LocationError, match=r"^--center .*: not a finite point$"):
        window_at(cross, x, y)


def test_window_at_rejects_a_bad_size(cross):
    with pytest.raises(LocationError, match=r"^--center 0,0: bad window"):
        window_at(cross, 0.0, 0.0, size=0.0)


# ---- candidates --------------------------------------------------------------------------------
def test_single_crossing_is_one_signalised_candidate(cross):
    assert TLS_BONUS > 0
    assert candidates(cross) == [Location(Window(0.0, 0.0, 0.0, 100.0), "signalised", "c", 4 + TLS_BONUS)]


def test_merges_lane_drops_and_diverges(ramps):
    got = sorted((c.junction_id, c.kind, c.score) for c in candidates(ramps))
    assert got == [("b", "merge_diverge", 2.0), ("c", "merge_diverge", 1.0), ("m", "merge_diverge", 3.0)]


def test_city_candidates(city):
    cands = candidates(city)
    assert Counter(c.kind for c in cands) == {"unsignalised": 130, "signalised": 27, "roundabout": 2}
    ring_nodes = {n for rb in city.sumo_net.getRoundabouts() for n in rb.getNodes()}
    assert all((c.junction_id in ring_nodes) == (c.kind == "roundabout") for c in cands)
    for c in cands:
        if c.kind == "signalised":
            assert city.sumo_net.getNode(c.junction_id).getType().startswith("traffic_light")
    assert len({c.junction_id for c in cands}) == len(cands)


# ---- auto_windows ------------------------------------------------------------------------------
def test_auto_windows_is_deterministic_and_depends_on_the_seed(city):
    runs = {s: auto_windows(city, 12, seed=s) for s in (0, 1, 2)}
    assert auto_windows(city, 12, seed=0) == runs[0]
    assert runs[0] != runs[1] and runs[1] != runs[2] and runs[0] != runs[2]
    assert all(len(r) == 12 for r in runs.values())


def test_auto_windows_is_deterministic_across_loads(grid):
    again = Network.load(grid.path)
    assert auto_windows(again, 7, seed=3) == auto_windows(grid, 7, seed=3)


def test_auto_windows_are_separated_on_roads_and_at_junctions(city):
    locs = auto_windows(city, 20, seed=5)
    assert len(locs) == 20
    assert _min_separation(locs) >= 50.0
    assert all(city.has_road(loc.window) for loc in locs)
    assert all(loc.window.yaw == 0.0 and loc.window.size == 100.0 for loc in locs)
    assert len({loc.junction_id for loc in locs}) == 20
    by_id = {c.junction_id: c for c in candidates(city)}
    assert all(by_id[loc.junction_id] == loc for loc in locs)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_separation_scales_with_size(city, seed):
    # 15 windows 200 m apart fit easily in 2x2 km, but score-weighted picks alone would come closer
    locs = auto_windows(city, 15, seed=seed, size=400.0)
    assert len(locs) == 15 and _min_separation(locs) >= 200.0
    assert all(loc.window.size == 400.0 and city.has_road(loc.window) for loc in locs)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_auto_windows_take_kinds_round_robin(city, seed):
    kinds = Counter(loc.kind for loc in auto_windows(city, 8, seed=seed))
    assert kinds == {"signalised": 3, "unsignalised": 3, "roundabout": 2}   # only 2 roundabouts exist


def test_junctions_are_drawn_in_proportion_to_score(ramps):
    # scores m 3, b 2, c 1: expected first picks over 300 seeds ~150 / 100 / 50 (uniform: 100 each)
    first = Counter(auto_windows(ramps, 1, seed=s)[0].junction_id for s in range(300))
    assert first["m"] > first["b"] > first["c"] and first["m"] >= 2 * first["c"]


def test_more_windows_than_candidates(grid):
    cands = candidates(grid)
    assert len(cands) == 5   # 3x3 grid: the 4 edge middles (3 arms) and the centre; corners have 2 arms
    locs = auto_windows(grid, 12, seed=0)
    assert len(locs) == 12
    assert {loc.junction_id for loc in locs[:5]} == {c.junction_id for c in cands}
    assert all(loc.window.yaw != 0.0 for loc in locs[5:])
    assert len({loc.window for loc in locs}) == 12
    assert all(grid.has_road(loc.window) for loc in locs)


def test_separation_is_relaxed_before_reusing_candidates(grid):
    # size 250: the centre junction is 100 m < 125 m from each edge middle, yet all 5 junctions are used
    locs = auto_windows(grid, 5, seed=0, size=250.0)
    assert sorted(loc.junction_id for loc in locs) == sorted(c.junction_id for c in candidates(grid))
    assert all(loc.window.yaw == 0.0 for loc in locs)


def test_the_first_kind_depends_on_the_seed(city):
    assert {auto_windows(city, 1, seed=s)[0].kind for s in range(10)} == {"signalised", "unsignalised",
                                                                          "roundabout"}


def test_one_candidate_reused_with_different_yaws(cross):
    locs = auto_windows(cross, 5, seed=0)
    assert [(loc.window.cx, loc.window.cy, loc.kind) for loc in locs] == [(0.0, 0.0, "signalised")] * 5
    assert len({loc.window.yaw for loc in locs}) == 5


def test_no_junction_candidates_fall_back_to_road_points(diagonal_net):
    net = Network.load(diagonal_net)
    assert candidates(net) == []
    locs = auto_windows(net, 3, seed=0)
    assert [(loc.kind, loc.junction_id) for loc in locs] == [("road", None)] * 3
    assert _min_separation(locs) >= 50.0
    assert all(net.has_road(loc.window) for loc in locs)
    assert auto_windows(net, 3, seed=0) == locs and auto_windows(net, 3, seed=1) != locs


def test_n_zero_and_negative(cross):
    assert auto_windows(cross, 0) == []
    with pytest.raises(ValueError):
        auto_windows(cross, -1)


@pytest.mark.skipif(not os.path.exists(COLOGNE8), reason="real network not available")
def test_real_network_cologne8():
    net = Network.load(COLOGNE8)
    assert Counter(c.kind for c in candidates(net)) == {"unsignalised": 32, "signalised": 8,
                                                        "merge_diverge": 3}
    locs = auto_windows(net, 12, seed=0)
    assert auto_windows(net, 12, seed=0) == locs
    assert len(locs) == 12 and _min_separation(locs) >= 50.0
    assert all(net.has_road(loc.window) for loc in locs)
    assert {loc.kind for loc in locs} == {"unsignalised", "signalised", "merge_diverge"}
    assert set(KINDS) >= {loc.kind for loc in locs}


# ---- auto_windows with the host's traffic -------------------------------------------------------
def _node_xy(net: Network, node: str) -> tuple[float, float]:
    return tuple(net.sumo_net.getNode(node).getCoord()[:2])


def _queue(x0: float, x1: float, y: float, k: int) -> np.ndarray:
    return np.column_stack([np.linspace(x0, x1, k), np.full(k, y)])


def test_vehicles_in_counts_points_per_window_edge_included():
    windows = [Window(0.0, 0.0), Window(200.0, 0.0), Window(0.0, 0.0, math.pi / 4)]
    pts = np.array([[0.0, 0.0], [50.0, 50.0], [60.0, 0.0], [200.0, -49.0], [0.0, 70.0]])
    # the turned square reaches 70.7 m along the axes but not the upright one's corner (50, 50)
    assert vehicles_in(windows, pts).tolist() == [2, 1, 3]
    assert vehicles_in(windows, []).tolist() == [0, 0, 0] and vehicles_in(windows, None).tolist() == [0, 0, 0]
    assert vehicles_in([], pts).tolist() == []


def test_traffic_decides_where_the_windows_go(grid):
    # ten vehicles on the bottom row's road between two of its junctions: only the junction there holds them
    busy = next(c for c in candidates(grid) if c.window.cy == 0.0)
    pts = _queue(busy.window.cx - 45, busy.window.cx + 45, -1.6, 10)
    assert vehicles_in([c.window for c in candidates(grid)], pts).tolist().count(0) == 4
    for seed in range(10):
        locs = auto_windows(grid, 3, seed=seed, traffic=pts)
        assert locs[0] == busy and len({loc.junction_id for loc in locs}) == 3
        assert _min_separation(locs) >= 50.0   # then the layout's choice, spread as before
    assert {auto_windows(grid, 1, seed=s)[0].junction_id for s in range(10)} != {busy.junction_id}


def test_the_busier_half_drawn_in_proportion_to_their_vehicles(grid):
    # 9 vehicles at the bottom junction's window, 3 at the top one's, 1 each at the left and right ones
    by_xy = {(c.window.cx, c.window.cy): c.junction_id for c in candidates(grid)}
    bottom, top, left, right = by_xy[100.0, 0.0], by_xy[100.0, 200.0], by_xy[0.0, 100.0], by_xy[200.0, 100.0]
    pts = np.vstack([_queue(60, 140, -1.6, 9), _queue(60, 140, 201.6, 3), [[-1.6, 100.0], [201.6, 100.0]]])
    first = Counter(auto_windows(grid, 1, seed=s, traffic=pts)[0].junction_id for s in range(200))
    assert set(first) == {bottom, top}                  # at least the busy windows' median (2 vehicles)
    assert first[bottom] > 2 * first[top]              # expected 150 / 50
    four = auto_windows(grid, 4, seed=0, traffic=pts)
    assert {loc.junction_id for loc in four[:2]} == {bottom, top} and {loc.junction_id for loc in four[2:]} == {
        left, right}                                   # then the other windows holding vehicles


def test_traffic_windows_are_deterministic_and_spread(city):
    rng = np.random.default_rng(7)
    pts, _ = city.random_road_points(400, rng)
    locs = auto_windows(city, 12, seed=1, traffic=pts)
    assert auto_windows(city, 12, seed=1, traffic=pts[::-1]) == locs    # the order of vehicles is no matter
    assert auto_windows(city, 12, seed=2, traffic=pts) != locs
    assert len(locs) == 12 and _min_separation(locs) >= 25.0 and all(city.has_road(loc.window) for loc in locs)
    held = vehicles_in([loc.window for loc in locs], pts)
    layout = vehicles_in([loc.window for loc in auto_windows(city, 12, seed=1)], pts)
    assert held.min() > 0 and held.sum() > layout.sum()


def test_no_vehicle_in_any_window_keeps_the_layouts_choice(city, diagonal_net):
    far = np.array([[-5000.0, -5000.0], [9000.0, 0.0]])
    for seed in (0, 3):
        layout = auto_windows(city, 6, seed=seed)
        assert auto_windows(city, 6, seed=seed, traffic=far) == layout
        assert auto_windows(city, 6, seed=seed, traffic=np.empty((0, 2))) == layout
    diag = Network.load(diagonal_net)
    assert auto_windows(diag, 3, seed=0, traffic=far) == auto_windows(diag, 3, seed=0)


def test_road_windows_go_where_the_vehicles_are(diagonal_net):
    net = Network.load(diagonal_net)
    pts = np.column_stack([np.linspace(250, 290, 5)] * 2)   # near the road's far end
    locs = auto_windows(net, 2, seed=0, traffic=pts)
    assert [loc.kind for loc in locs] == ["road"] * 2 and _min_separation(locs) >= 50.0
    assert vehicles_in([locs[0].window], pts)[0] > 0
    assert vehicles_in([auto_windows(net, 1, seed=0)[0].window], pts)[0] == 0   # the layout's went elsewhere
