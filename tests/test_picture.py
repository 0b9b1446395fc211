"""Scene pictures explain themselves: legend, scale bar, north arrow, outlined boxes, sumo-gui's
world-aligned view, and readable paged contact sheets."""
from __future__ import annotations

import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.map.network import Network
from sumo_scendiff.map.picture import (
    KIND_COLOURS,
    contact_sheets,
    draw_scene,
    paginate,
    picture_view,
    scale_bar_metres,
)
from sumo_scendiff.map.raster import RasterConfig


@pytest.fixture(scope="module")
def net(cross_net):
    return Network.load(cross_net)


def _scene(window: Window, boxes) -> Scene:
    """Standing agents without observed trajectories (only the boxes are drawn)."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 5)
    n = len(boxes)
    traj = np.repeat(boxes[:, None, :3], 5, 1)
    return Scene(window, boxes, traj, np.zeros((n, 5), bool), np.zeros((n, 5)), np.zeros(n))


def _pixels_of(img, colour) -> np.ndarray:
    """(row, col) of the pixels exactly ``colour``."""
    return np.argwhere(np.all(img == np.array(colour, np.uint8), axis=-1))


def test_legend_scale_bar_and_north_arrow_are_drawn_in_their_corners(net):
    scene = _scene(Window(0.0, 0.0, 0.3), [[-20.0, 0.0, 0.0, 4.6, 1.8]])
    bare = draw_scene(net, scene, 600, legend=False)
    full = draw_scene(net, scene, 600)
    q = 600 // 4
    corners = {"legend": (slice(600 - q, 600), slice(0, q)), "scale bar": (slice(600 - q, 600), slice(600 - q, 600)),
               "north arrow": (slice(0, q), slice(600 - q, 600))}
    for name, (rows, cols) in corners.items():
        changed = np.any(full[rows, cols] != bare[rows, cols], axis=-1).mean()
        assert changed > 0.02, f"{name}: the corner is the bare map"
    # nothing else moves: the middle of the picture is the same
    assert np.array_equal(full[q:600 - q, q:600 - q], bare[q:600 - q, q:600 - q])


@pytest.mark.parametrize("world_aligned,pixels", [(True, 600), (False, 400), (True, 800)])
def test_scale_bar_is_as_long_as_its_metres(net, world_aligned, pixels):
    window = Window(0.0, 0.0, 0.0)
    img = draw_scene(net, _scene(window, np.zeros((0, 5))), pixels, world_aligned=world_aligned)
    mpp = RasterConfig(size=picture_view(window, world_aligned).size, pixels=pixels).metres_per_pixel
    metres = scale_bar_metres(mpp, pixels)
    assert metres in (10, 20)
    black = np.all(img[pixels // 2:, pixels // 2:] == 0, axis=-1)
    longest = 0
    for row in black:
        run = best = 0
        for v in row:
            run = run + 1 if v else 0
            best = max(best, run)
        longest = max(longest, best)
    assert longest == round(metres / mpp)


def test_touching_boxes_keep_an_outline_between_them(net):
    y = 30.0   # away from the roads, on the plain background
    boxes = [[-10.0, y, 0.0, 4.6, 1.8], [-10.0 + 4.6, y, 0.0, 4.6, 1.8]]   # rear of one = front of the other
    img = draw_scene(net, _scene(Window(0.0, 0.0, 0.0), boxes), 600, world_aligned=False, legend=False)
    cfg = RasterConfig(size=100.0, pixels=600)
    row = round((50.0 - y - 0.5) / cfg.metres_per_pixel - 0.5)   # off the heading tick along the axis
    c0 = round((50.0 - 10.0) / cfg.metres_per_pixel)            # first box's centre column
    c1 = round((50.0 - 10.0 + 4.6) / cfg.metres_per_pixel)      # second box's centre column
    line = img[row, c0:c1].astype(int)
    green = np.array(KIND_COLOURS["generated"])
    assert np.array_equal(line[0], green) and np.array_equal(line[-1], green)
    darkest = line.sum(axis=1).min()
    assert darkest < 0.6 * green.sum(), "no outline between the two boxes"


def test_world_aligned_view_puts_east_on_the_right_whatever_the_window_yaw(net):
    window = Window(0.0, 0.0, math.pi / 2)          # the window looks north
    east = window.world_to_scene(np.array([30.0, 0.0]))   # a vehicle 30 m east of the centre
    assert east[1] < -29.0                          # ... is to the window's right
    scene = _scene(window, [[east[0], east[1], float(window.yaw_to_scene(0.0)), 4.6, 1.8]])
    green = KIND_COLOURS["generated"]
    world = _pixels_of(draw_scene(net, scene, 600, legend=False), green)
    assert len(world) and world[:, 1].mean() > 400 and abs(world[:, 0].mean() - 300) < 10
    # its box lies along x (east), as sumo-gui shows it: wider than tall
    assert np.ptp(world[:, 1]) > 2 * np.ptp(world[:, 0])
    framed = _pixels_of(draw_scene(net, scene, 600, legend=False, world_aligned=False), green)
    assert framed[:, 0].mean() > 400 and abs(framed[:, 1].mean() - 300) < 10   # below: the window's right


def test_kinds_kept_tokens_and_the_ego_each_have_their_colour(net):
    window = Window(0.0, 0.0, 0.0)
    scene = _scene(window, [[-30.0, 30.0, 0.0, 4.6, 1.8], [30.0, 30.0, 0.0, 4.6, 1.8]])
    img = draw_scene(net, scene, 600, kinds=["generated", "token"], kept=[[0.0, -30.0, 0.0, 4.6, 1.8]],
                     token_xy=[[30.0, 30.0]], ego=(0.0, -30.0), world_aligned=False, legend=False)
    for kind, (x, y) in (("generated", (-30, 30)), ("token", (30, 30)), ("kept", (0, -30))):
        at = _pixels_of(img, KIND_COLOURS[kind])
        centre = np.array([(50 - y) * 6 - 0.5, (x + 50) * 6 - 0.5])
        assert len(at) and np.abs(at.mean(axis=0) - centre).max() < 3, kind
    with pytest.raises(ValueError, match="kinds"):
        draw_scene(net, scene, 200, kinds=["generated"])


def test_export_picture_tells_generated_token_and_kept_apart(net, tmp_path):
    from sumo_scendiff.sim.export import write_picture
    window = Window(0.0, 0.0, 0.0)
    scene = _scene(window, [[-30.0, 30.0, 0.0, 4.6, 1.8], [30.0, 30.0, 0.0, 4.6, 1.8]])
    tokens = [{"x": 30.0, "y": 30.0, "heading": 0.0, "length": 4.6, "width": 1.8},
              {"x": 0.0, "y": -30.0, "heading": 0.0, "length": 4.6, "width": 1.8}]
    from sumo_scendiff.sim.cosim import Seeding
    from sumo_scendiff.sim.seeding import SeedReport
    seeding = Seeding(scene, SeedReport(ids={0: "sd0", 1: "sd1"}), tokens, ["user", "veh7"], [None, 0],
                      seed=0, p_mask=0.5)
    path = str(tmp_path / "scene.png")
    write_picture(path, seeding, net)
    img = cv2.imread(path)
    for kind in ("generated", "token", "kept"):
        assert len(_pixels_of(img, KIND_COLOURS[kind])) > 20, kind


def test_contact_sheets_are_paged_and_readable():
    assert [len(p) for p in paginate(list(range(10)), 4)] == [4, 4, 2]
    with pytest.raises(ValueError):
        paginate([1], 0)
    imgs = [np.full((600, 600, 3), 10 * k, np.uint8) for k in range(10)]
    sheets = contact_sheets(imgs, [(f"s{k:04d}", "p_mask 0.50") for k in range(10)], tile=400, ncol=2, per_page=4)
    assert len(sheets) == 3
    first, last = sheets[0], sheets[-1]
    assert first.shape[1] >= 2 * 400 and first.shape[0] > 2 * 400   # two rows of two tiles with captions
    assert last.shape[0] < first.shape[0] / 1.5                      # one row: the last two tiles
    # the caption band holds text (dark pixels) above each tile
    assert (first[:20, :400] < 128).any()
    assert contact_sheets([]) == []


@pytest.mark.parametrize("world_aligned,direction", [(True, (0, -1)), (False, (1, 0))])
def test_north_arrow_points_to_world_north(net, world_aligned, direction):
    """A window looking north (yaw pi/2): north is up in sumo-gui's view, ahead (right) in the window's."""
    img = draw_scene(net, _scene(Window(0.0, 0.0, math.pi / 2), np.zeros((0, 5))), 600, world_aligned=world_aligned)
    r = 18                                    # the badge of a 600 px picture, top right
    centre = np.array([600 - 8 - r, 8 + r])   # (col, row)
    badge = img[:2 * r + 16, 600 - 2 * r - 16:]
    head = np.argwhere(np.all(badge == 40, axis=-1))[:, ::-1] + [600 - 2 * r - 16, 0]
    offset = head.mean(axis=0) - centre
    assert len(head) > 20 and offset @ np.array(direction) > 0.3 * r


def test_traffic_lights_colour_their_approaches_and_join_the_legend(net):
    from sumo_scendiff.map.picture import LIGHTS
    scene = _scene(Window(0.0, 0.0, 0.0), [])
    n = len(net.signal_links)
    east_green = "".join("G" if net.lanes[ln.lane].id == "wc_0" else "r"
                         for ln in sorted(net.signal_links, key=lambda ln: ln.index))
    assert len(east_green) == n
    plain = draw_scene(net, scene, 600)
    scene.meta["signals"] = {"c": east_green}
    lit = draw_scene(net, scene, 600)
    for name in ("green light", "red light"):
        tint, line = LIGHTS[name][1], LIGHTS[name][0]
        assert len(_pixels_of(lit, tint)) > 200 and len(_pixels_of(plain, tint)) == 0, name
        assert len(_pixels_of(lit, line)) > 10, f"{name}: the stop line in the light's colour"
    # the legend names both (its swatches are in the bottom-left quarter)
    corner = lit[450:, :150]
    assert len(_pixels_of(corner, LIGHTS["green light"][1])) and len(_pixels_of(corner, LIGHTS["red light"][1]))
    assert not len(_pixels_of(lit, LIGHTS["amber light"][1]))
