"""The fixed conventions of DESIGN.md, pinned with numbers."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_scendiff.core.geometry import (
    Window,
    metres_to_pixels,
    pixels_to_metres,
    pose_to_sumo,
    sumo_angle_to_yaw,
    sumo_to_pose,
    wrap_angle,
    yaw_to_sumo_angle,
)
from sumo_scendiff.map.network import Network
from sumo_scendiff.map.raster import (
    LANE_DIR_BINS,
    LANE_DIR_CHANNELS,
    MAP_CHANNELS,
    RasterConfig,
    direction_bins,
    render_agents,
    render_map,
)


def test_sumo_angle_to_yaw_cardinal_directions():
    # SUMO: degrees clockwise from north. North = 0 -> yaw pi/2; east = 90 -> 0; south -> -pi/2; west -> pi
    assert sumo_angle_to_yaw(0.0) == pytest.approx(math.pi / 2)
    assert sumo_angle_to_yaw(90.0) == pytest.approx(0.0)
    assert sumo_angle_to_yaw(180.0) == pytest.approx(-math.pi / 2)
    assert sumo_angle_to_yaw(270.0) == pytest.approx(math.pi)  # wrapped to (-pi, pi]
    assert yaw_to_sumo_angle(math.pi / 4) == pytest.approx(45.0)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)


def test_front_bumper_to_centre_and_back():
    # a 5 m car whose front bumper SUMO reports at (100, 50), driving north-east (SUMO angle 45)
    cx, cy, yaw = sumo_to_pose(100.0, 50.0, 45.0, 5.0)
    assert yaw == pytest.approx(math.pi / 4)
    assert (cx, cy) == pytest.approx((100 - 2.5 / math.sqrt(2), 50 - 2.5 / math.sqrt(2)))
    fx, fy, ang = pose_to_sumo(cx, cy, yaw, 5.0)
    assert (fx, fy, ang) == pytest.approx((100.0, 50.0, 45.0))


def test_recorded_vehicle_has_centre_and_yaw_from_sumo_front_bumper(diagonal_net):
    """Real SUMO: a vehicle placed with its front bumper at a known point is recorded at the box centre."""
    import libsumo as traci

    from sumo_scendiff.data.record import _Tracker
    traci.start(["sumo", "-n", diagonal_net, "--no-step-log", "--no-warnings"])
    try:
        traci.route.add("r", ["ab"])
        traci.vehicle.add("v", "r", departPos="100", departSpeed="0")
        traci.vehicle.setLength("v", 6.0)
        traci.vehicle.setSpeedMode("v", 0)
        tracker = _Tracker(traci)
        traci.simulationStep()
        tracker.step()
        traci.vehicle.setSpeed("v", 0.0)
        fx, fy = traci.vehicle.getPosition("v")
        angle = traci.vehicle.getAngle("v")
        assert angle == pytest.approx(45.0, abs=1e-6)
        # the lane is offset from the edge axis, but the vehicle's heading is the lane's: 45 deg
        cx, cy, yaw = tracker.steps[-1]["v"][:3]
        assert yaw == pytest.approx(math.pi / 4, abs=1e-6)
        assert cx == pytest.approx(fx - 3.0 * math.cos(math.pi / 4), abs=1e-6)
        assert cy == pytest.approx(fy - 3.0 * math.sin(math.pi / 4), abs=1e-6)
        # and SUMO's front bumper lies at departPos = 100 m along the lane
        lane_start = np.array(traci.lane.getShape(traci.vehicle.getLaneID("v"))[0])
        assert np.hypot(fx - lane_start[0], fy - lane_start[1]) == pytest.approx(
            traci.vehicle.getLanePosition("v"), abs=1e-3)
    finally:
        traci.close()


def test_window_rotation_maps_known_point_to_expected_pixel():
    # window at (1000, 2000) looking north (yaw pi/2): a world point 20 m north and 10 m east of the
    # centre is 20 m ahead (scene x = 20) and 10 m to the right (scene y = -10)
    w = Window(1000.0, 2000.0, math.pi / 2, 100.0)
    s = w.world_to_scene([1010.0, 2020.0])
    assert s == pytest.approx([20.0, -10.0])
    assert w.scene_to_world(s) == pytest.approx([1010.0, 2020.0])
    # 128 px over 100 m: col = (x + 50) * 1.28 - 0.5, row = (50 - y) * 1.28 - 0.5
    col, row = metres_to_pixels(s, 100.0, (128, 128))
    assert (col, row) == pytest.approx((70 * 1.28 - 0.5, 60 * 1.28 - 0.5))
    # the window centre is the corner shared by the four middle pixels; the +y edge is row -0.5
    assert metres_to_pixels([0.0, 0.0], 100.0, (128, 128)) == pytest.approx([63.5, 63.5])
    assert metres_to_pixels([-50.0, 50.0], 100.0, (128, 128)) == pytest.approx([-0.5, -0.5])
    assert pixels_to_metres([[col, row]], 100.0, (128, 128))[0] == pytest.approx([20.0, -10.0])


def test_lane_direction_channels_have_cos_sin_at_the_right_pixels(diagonal_net):
    net = Network.load(diagonal_net)
    cfg = RasterConfig(pixels=128)
    ci, si, li = (MAP_CHANNELS.index(c) for c in ("lane_cos", "lane_sin", "centerline"))
    lane = next(ln for ln in net.lanes if ln.car and not ln.internal)
    mid = lane.shape.mean(axis=0)
    for win_yaw in (0.0, math.pi / 4, -2.0):
        w = Window(float(mid[0]), float(mid[1]), win_yaw)
        m = render_map(net, w, cfg)
        # the lane passes through the window centre; its heading in the window frame is pi/4 - win_yaw
        rel = math.pi / 4 - win_yaw
        col, row = np.round(metres_to_pixels(w.world_to_scene(mid), cfg.size, cfg.shape)).astype(int)
        assert m[li, row, col] == 1.0
        assert m[ci, row, col] == pytest.approx(math.cos(rel), abs=1e-5)
        assert m[si, row, col] == pytest.approx(math.sin(rel), abs=1e-5)
        # 20 m to the side of the road there is no lane
        side = w.world_to_scene(mid + 20.0 * np.array([-1.0, 1.0]) / math.sqrt(2))
        c2, r2 = np.round(metres_to_pixels(side, cfg.size, cfg.shape)).astype(int)
        assert m[li, r2, c2] == 0.0 and m[MAP_CHANNELS.index("drivable"), r2, c2] == 0.0
        assert m[MAP_CHANNELS.index("drivable"), row, col] == 1.0
        # the direction histogram holds the lane's heading in its two nearest bins
        bins, weights = direction_bins(np.array([rel]))
        hist = np.zeros(LANE_DIR_BINS, np.float32)
        hist[bins[0]] = weights[0]
        assert m[[MAP_CHANNELS.index(c) for c in LANE_DIR_CHANNELS], row, col] == pytest.approx(hist, abs=1e-5)


def test_direction_bins_interpolate_linearly_and_recover_the_yaw():
    yaw = np.array([0.0, 0.3, math.pi / 2, -0.1, math.pi, 2 * math.pi - 1e-4])
    bins, weights = direction_bins(yaw)
    step = 2 * math.pi / LANE_DIR_BINS
    assert np.allclose(weights.sum(1), 1.0) and np.all(weights >= 0)
    assert bins[:, 0].tolist() == [0, 0, 2, LANE_DIR_BINS - 1, LANE_DIR_BINS // 2, LANE_DIR_BINS - 1]
    assert np.array_equal(bins[:, 1], (bins[:, 0] + 1) % LANE_DIR_BINS)
    recovered = (bins[:, 0] + weights[:, 1]) * step
    assert np.allclose(np.angle(np.exp(1j * (recovered - yaw))), 0.0, atol=1e-5)


def test_lane_direction_histogram_keeps_both_crossing_lanes(cross_net):
    """Inside a junction, where lane_cos / lane_sin hold the internal lane drawn last, the direction
    histogram keeps every lane through the pixel: here the eastbound and northbound through lanes
    crossing at (1.6, -1.6) (right-hand traffic, 3.2 m lanes)."""
    net = Network.load(cross_net)
    for win_yaw, east_bin in ((0.0, 0), (-math.pi / 2, 2)):  # a window turned by -90 deg sees east at +90
        w = Window(0.0, 0.0, win_yaw)
        m = render_map(net, w)
        col, row = np.round(metres_to_pixels(w.world_to_scene([1.6, -1.6]), 100.0, (128, 128))).astype(int)
        hist = m[[MAP_CHANNELS.index(c) for c in LANE_DIR_CHANNELS], row, col]
        north_bin = (east_bin + LANE_DIR_BINS // 4) % LANE_DIR_BINS
        assert hist[east_bin] == pytest.approx(1.0) and hist[north_bin] == pytest.approx(1.0)
        cos_sin = m[[MAP_CHANNELS.index("lane_cos"), MAP_CHANNELS.index("lane_sin")], row, col]
        one = [np.allclose(cos_sin, [math.cos(a - win_yaw), math.sin(a - win_yaw)], atol=1e-5)
               for a in (0.0, math.pi / 2)]
        assert sum(one) == 1   # the single-direction channels kept only one of the two
        # away from the roads the histogram is empty
        col, row = np.round(metres_to_pixels(w.world_to_scene([30.0, 30.0]), 100.0, (128, 128))).astype(int)
        assert not m[[MAP_CHANNELS.index(c) for c in LANE_DIR_CHANNELS], row, col].any()


def test_agent_raster_fills_the_box_with_heading_and_deltas():
    cfg = RasterConfig(pixels=128)
    yaw = 0.3
    boxes = np.array([[10.0, -5.0, yaw, 5.0, 2.0]])
    v = np.array([math.cos(yaw), math.sin(yaw)]) * 6.0  # 6 m/s along the heading
    t = np.arange(-2, 3)[:, None]
    traj = np.concatenate([boxes[:, None, :2] + t[None] * v, np.full((1, 5, 1), yaw)], axis=-1)
    mask = np.ones((1, 5), bool)
    mask[0, 0] = False  # t = -2 unobserved: the -2 delta is masked
    x = render_agents(boxes, traj, mask, cfg)
    col, row = np.round(metres_to_pixels([10.0, -5.0], cfg.size, cfg.shape)).astype(int)
    assert x[0, row, col] == 1.0
    assert x[1, row, col] == pytest.approx(math.cos(yaw)) and x[2, row, col] == pytest.approx(math.sin(yaw))
    assert x[3, row, col] == 0.0  # alpha_-2
    assert x[6, row, col] == 1.0  # alpha_-1
    assert x[7, row, col] == pytest.approx(v[0] / 30 + 0.5) and x[8, row, col] == pytest.approx(v[1] / 30 + 0.5)
    # every pixel whose centre lies inside the box is filled; none more than a pixel outside it
    from sumo_scendiff.core.geometry import pixel_centres
    xy = pixel_centres(cfg.size, cfg.shape) - boxes[0, :2]
    along = xy[..., 0] * math.cos(yaw) + xy[..., 1] * math.sin(yaw)
    across = -xy[..., 0] * math.sin(yaw) + xy[..., 1] * math.cos(yaw)
    inside = (np.abs(along) < 2.5) & (np.abs(across) < 1.0)
    near = (np.abs(along) < 2.5 + cfg.metres_per_pixel) & (np.abs(across) < 1.0 + cfg.metres_per_pixel)
    assert inside.sum() > 10 and np.all(x[0][inside] == 1.0)
    assert np.all(x[0][~near] == 0.0)
