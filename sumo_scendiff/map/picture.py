"""Pictures of scenes (OpenCV), in the style of the paper's figures with what a reader needs to
read them alone: a legend, a scale bar, a north arrow, outlined boxes, the ego marked.

    img = draw_scene(net, scene, pixels=600, title="ground truth")    # BGR uint8, square
    img = draw_scene(net, scene, kinds=["generated", "token"], kept=boxes, token_xy=xy, ego=(0, 0))
    cv2.imwrite("scene.png", img)
    cv2.imwrite("sheet.png", contact_sheet([[img_a, img_b], [img_c, img_d]]))
    for k, page in enumerate(contact_sheets(imgs, captions, tile=400, per_page=24)): ...

By default a scene is drawn as sumo-gui shows the network (world-aligned: +x right, north up),
whatever its window's yaw; the window is the outlined square, turned with its yaw, and the map
outside it is dimmed. ``world_aligned=False`` draws the window's own frame (x to the right).
"""
from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from ..core.geometry import Window, box_corners, metres_to_pixels
from .raster import MAP_CHANNELS, RasterConfig, render_map

_SHIFT = 4
PAST, FUTURE = np.array([203, 102, 255.0]), np.array([230, 130, 30.0])  # BGR pink -> blue
KINDS = ("generated", "kept", "token")
# BGR: generated green, vehicles already in the simulation purple, agents realising a token orange.
KIND_COLOURS = {"generated": (60, 200, 60), "kept": (170, 70, 130), "token": (0, 150, 255)}
KIND_LABELS = {"generated": "generated", "kept": "kept (already in SUMO)", "token": "realises a token"}
TOKEN = (0, 150, 255)
# traffic lights (BGR): the approach tinted, the stop line in the light's colour
LIGHTS = {"green light": ((60, 170, 60), (140, 175, 140)), "amber light": ((0, 170, 240), (130, 165, 185)),
          "red light": ((50, 50, 210), (140, 140, 190))}
EGO = (20, 20, 20)
SCALE_BAR = (0, 0, 0)        # pure black: nothing else in a picture is drawn in it
SCALE_STEPS = (1, 2, 5, 10, 20, 50, 100, 200, 500)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _outline(colour) -> tuple[int, int, int]:
    return tuple(int(c * 0.35) for c in colour)


def light_classes(m: np.ndarray) -> dict[str, np.ndarray]:
    """Per :data:`LIGHTS` name, the pixels of a map raster ``m`` whose signal channels show it
    (outside junctions: the approaches)."""
    ch = {name: m[i] for i, name in enumerate(MAP_CHANNELS)}
    road = ch["junction"] <= 0
    go, stop = ch["signal_go"], ch["signal_stop"]
    return {"green light": road & (go > 0) & (stop <= 0), "amber light": road & (stop > 0) & (stop < 1),
            "red light": road & (stop >= 1)}


def map_background(net, window, cfg: RasterConfig, signals: dict[str, str] | None = None) -> np.ndarray:
    """Grey drivable area, darker junctions, light sidewalks, white lane centre lines, dark stop
    lines; with ``signals`` (tls id -> state) each controlled approach tinted and its stop line
    coloured as its light shows."""
    return _background(net, window, cfg, signals)[0]


def _background(net, window, cfg: RasterConfig, signals: dict[str, str] | None):
    """:func:`map_background` and the names of the lights it shows."""
    m = render_map(net, window, cfg, signals=signals)
    ch = {name: m[i] for i, name in enumerate(MAP_CHANNELS)}
    img = np.full(cfg.shape + (3,), 245, np.uint8)
    img[ch["sidewalk"] > 0] = (225, 225, 225)
    img[ch["crossing"] > 0] = (200, 200, 200)
    img[ch["drivable"] > 0] = (150, 150, 150)
    img[ch["junction"] > 0] = (130, 130, 130)
    lights = light_classes(m) if signals else {}
    for name, px in lights.items():
        img[px] = LIGHTS[name][1]
    img[ch["centerline"] > 0] = (235, 235, 235)
    img[ch["stop_line"] > 0] = (70, 70, 70)
    for name, px in lights.items():
        img[px & (ch["stop_line"] > 0)] = LIGHTS[name][0]
    return img, [name for name, px in lights.items() if px.any()]


def picture_view(window: Window, world_aligned: bool = True) -> Window:
    """The square a picture of ``window`` shows: the window itself, or (world-aligned) a square
    at yaw 0 around its centre, side * sqrt(2), so the window fits at any yaw and every picture of
    a window size has the same scale."""
    if not world_aligned:
        return window
    return Window(window.cx, window.cy, 0.0, window.size * float(np.sqrt(2.0)))


def scale_bar_metres(metres_per_pixel: float, pixels: int) -> int:
    """The longest round length whose bar stays within a fifth of the picture's width."""
    fits = [m for m in SCALE_STEPS if m / metres_per_pixel <= 0.2 * pixels]
    return fits[-1] if fits else SCALE_STEPS[0]


class _Canvas:
    """Scene-frame metres -> pixels of a picture showing ``view`` (the one place that converts)."""

    def __init__(self, window: Window, view: Window, pixels: int):
        self.window, self.view = window, view
        self.cfg = RasterConfig(size=view.size, pixels=pixels)
        # annotation size relative to a 600 px picture; small pictures keep legible text
        self.u = float(np.clip(pixels / 600.0, 0.8, 2.0))

    def xy(self, xy_scene) -> np.ndarray:
        """Continuous (col, row) pixel coordinates."""
        xy = np.asarray(xy_scene, np.float64)
        if self.view != self.window:
            xy = self.view.world_to_scene(self.window.scene_to_world(xy))
        return metres_to_pixels(xy, self.cfg.size, self.cfg.shape)

    def px(self, xy_scene) -> np.ndarray:
        """OpenCV fixed-point (shift = _SHIFT) pixel coordinates, int32."""
        return np.round(self.xy(xy_scene) * (1 << _SHIFT)).astype(np.int32)

    def north(self) -> np.ndarray:
        """Unit vector in pixel (col, row) space pointing to world +y (north in SUMO)."""
        return np.array([np.sin(self.view.yaw), -np.cos(self.view.yaw)])


def _text(img, text, org, scale, colour=(0, 0, 0), thick=1) -> None:
    cv2.putText(img, text, (int(org[0]), int(org[1])), _FONT, scale, colour, thick, cv2.LINE_AA)


def _panel(img, x0, y0, x1, y1) -> None:
    """A light backing for annotations, so they read over the map."""
    h, w = img.shape[:2]
    x0, y0, x1, y1 = max(0, int(x0)), max(0, int(y0)), min(w, int(x1)), min(h, int(y1))
    if x1 > x0 and y1 > y0:
        img[y0:y1, x0:x1] = (0.2 * img[y0:y1, x0:x1] + 0.8 * 255).astype(np.uint8)


def _trajectories(img, cv: _Canvas, scene) -> None:
    thick = max(1, round(2 * cv.u))
    for i in range(len(scene)):
        pix = cv.px(scene.traj[i, scene.traj_mask[i], :2])
        for k in range(len(pix) - 1):
            c = PAST + (FUTURE - PAST) * (k / max(len(pix) - 2, 1))
            cv2.line(img, tuple(pix[k]), tuple(pix[k + 1]), tuple(int(v) for v in c), thick, cv2.LINE_AA, _SHIFT)


def _boxes(img, cv: _Canvas, boxes: np.ndarray, colours: Sequence) -> None:
    """Filled boxes with a darker outline (adjacent boxes stay apart) and a tick to the front."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 5)
    for b, colour in zip(boxes, colours):
        corners = cv.px(box_corners(*b))
        dark = _outline(colour)
        cv2.fillPoly(img, [corners], colour, cv2.LINE_AA, _SHIFT)
        cv2.polylines(img, [corners], True, dark, 1, cv2.LINE_AA, _SHIFT)
        front = b[:2] + 0.5 * b[3] * np.array([np.cos(b[2]), np.sin(b[2])])
        cv2.line(img, tuple(cv.px(b[:2])), tuple(cv.px(front)), dark, 1, cv2.LINE_AA, _SHIFT)


def _window_outline(img, cv: _Canvas) -> None:
    """Dim the map outside the window and draw the window's (turned) square."""
    h = 0.5 * cv.window.size
    square = cv.px(np.array([[h, h], [-h, h], [-h, -h], [h, -h]]))
    inside = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(inside, [square], 1, cv2.LINE_8, _SHIFT)
    out = inside == 0
    img[out] = (0.45 * img[out] + 0.55 * 255).astype(np.uint8)
    cv2.polylines(img, [square], True, (90, 90, 90), max(1, round(cv.u)), cv2.LINE_AA, _SHIFT)


def _ego(img, cv: _Canvas, ego) -> None:
    p = cv.px(np.asarray(ego, np.float64)[:2])
    r = round(4.0 / cv.cfg.metres_per_pixel) << _SHIFT
    cv2.circle(img, tuple(p), r, EGO, max(2, round(2 * cv.u)), cv2.LINE_AA, _SHIFT)
    c = cv.xy(np.asarray(ego, np.float64)[:2])
    _text(img, "ego", (c[0] + (r >> _SHIFT) + 2, c[1] - (r >> _SHIFT)), 0.45 * cv.u, EGO, 1)


def _legend(img, cv: _Canvas, kinds: Sequence[str], token_ring: bool, ego: bool,
            lights: Sequence[str] = ()) -> None:
    """Bottom left: trajectory colours, one swatch per kind of vehicle, the token ring, the ego,
    the traffic lights shown."""
    u, fs = cv.u, 0.4 * cv.u
    line, sw = round(17 * u), round(22 * u)
    rows = ["traj"] + list(kinds) + (["ring"] if token_ring else []) + (["ego"] if ego else []) + list(lights)
    labels = {"traj": "past -2 s .. future +2 s", "ring": "asked token", "ego": "ego", **KIND_LABELS,
              **{k: k for k in LIGHTS}}
    width = sw + 12 + max(cv2.getTextSize(labels[r], _FONT, fs, 1)[0][0] for r in rows) + 6
    h = img.shape[0]
    x0, y0 = 4, h - 4 - line * len(rows) - 6
    _panel(img, x0, y0, x0 + width, h - 4)
    for k, r in enumerate(rows):
        cy = y0 + 3 + line * k + line // 2
        xs = x0 + 5
        if r == "traj":
            for j in range(4):
                c = tuple(int(v) for v in PAST + (FUTURE - PAST) * (j / 3))
                cv2.line(img, (xs + j * sw // 4, cy), (xs + (j + 1) * sw // 4, cy), c, max(1, int(2 * u)), cv2.LINE_AA)
        elif r in LIGHTS:
            hh = max(2, line // 4)
            cv2.rectangle(img, (xs, cy - hh), (xs + sw, cy + hh), LIGHTS[r][1], -1)
            cv2.rectangle(img, (xs + sw - 4, cy - hh - 1), (xs + sw, cy + hh + 1), LIGHTS[r][0], -1)
        elif r in KIND_COLOURS:
            hh = max(2, line // 4)
            cv2.rectangle(img, (xs, cy - hh), (xs + sw, cy + hh), KIND_COLOURS[r], -1)
            cv2.rectangle(img, (xs, cy - hh), (xs + sw, cy + hh), _outline(KIND_COLOURS[r]), 1)
        else:
            colour = TOKEN if r == "ring" else EGO
            cv2.circle(img, (xs + sw // 2, cy), max(3, line // 2 - 2), colour, max(1, round(1.5 * u)), cv2.LINE_AA)
        _text(img, labels[r], (xs + sw + 7, cy + int(5 * u)), fs)


def _scale_bar(img, cv: _Canvas) -> None:
    """Bottom right: a black bar exactly N metres long, labelled."""
    mpp = cv.cfg.metres_per_pixel
    metres = scale_bar_metres(mpp, cv.cfg.pixels)
    length = round(metres / mpp)
    h, w = img.shape[:2]
    bar_h = max(3, round(4 * cv.u))
    x1, y1 = w - 10, h - 10
    x0 = x1 - length
    label = f"{metres} m"
    fs = 0.45 * cv.u
    (tw, th), _ = cv2.getTextSize(label, _FONT, fs, 1)
    _panel(img, min(x0, x1 - tw) - 6, y1 - bar_h - th - 12, w - 4, h - 4)
    img[y1 - bar_h:y1, x0:x1] = SCALE_BAR
    _text(img, label, (x0 + (length - tw) // 2, y1 - bar_h - 5), fs, (40, 40, 40))


def _north_arrow(img, cv: _Canvas) -> None:
    """Top right: an arrow to world +y (north in SUMO networks), turned with the view."""
    r = round(18 * cv.u)
    w = img.shape[1]
    c = np.array([w - 8 - r, 8 + r], np.float64)
    cv2.circle(img, (int(c[0]), int(c[1])), r + 3, (255, 255, 255), -1, cv2.LINE_AA)
    cv2.circle(img, (int(c[0]), int(c[1])), r + 3, (120, 120, 120), 1, cv2.LINE_AA)
    d = cv.north()
    side = np.array([-d[1], d[0]]) * r * 0.4
    tip, base = c + d * (r - 1), c + d * (r * 0.05)
    head = np.round(np.array([tip, base + side, base - side]) * (1 << _SHIFT)).astype(np.int32)
    cv2.fillPoly(img, [head], (40, 40, 40), cv2.LINE_AA, _SHIFT)
    fs = 0.42 * cv.u
    (tw, th), _ = cv2.getTextSize("N", _FONT, fs, 1)
    lab = c - d * (r * 0.45)   # the letter on the arrow's tail side
    _text(img, "N", (lab[0] - tw / 2, lab[1] + th / 2), fs, (40, 40, 40))


def _title(img, title: str, u: float, reserve: int) -> None:
    fs = 0.5 * u
    room = img.shape[1] - reserve - 14
    while fs > 0.3 and cv2.getTextSize(title, _FONT, fs, 1)[0][0] > room:
        fs -= 0.02
    (tw, th), _ = cv2.getTextSize(title, _FONT, fs, 1)
    _panel(img, 4, 4, 4 + tw + 8, 4 + th + 10)
    _text(img, title, (8, 4 + th + 4), fs)


def draw_scene(net, scene, pixels: int = 600, token_xy: np.ndarray | None = None, title: str = "",
               kinds: Sequence[str] | None = None, kept: np.ndarray | None = None, ego=None,
               world_aligned: bool = True, legend: bool = True) -> np.ndarray:
    """The scene on its map, ``pixels`` square (BGR uint8).

    ``kinds``: per agent of ``scene``, one of :data:`KINDS` (default: all "generated");
    ``kept``: (M, 5) scene-frame boxes of vehicles already in the simulation (drawn as "kept",
    without trajectories); ``token_xy``: scene-frame token positions, circled; ``ego``: the ego's
    scene-frame position (x, y, ...), or an agent index, ringed. ``legend=False`` leaves out the
    legend, scale bar and north arrow (for small side-by-side tiles). The traffic lights the scene
    was generated with (``scene.meta["signals"]``) colour their approaches."""
    window = scene.window
    cv = _Canvas(window, picture_view(window, world_aligned), pixels)
    signals = scene.meta.get("signals") or None
    img, shown_lights = _background(net, cv.view, cv.cfg, signals)
    if world_aligned:
        _window_outline(img, cv)
    kinds = ["generated"] * len(scene) if kinds is None else list(kinds)
    if len(kinds) != len(scene) or set(kinds) - set(KINDS):
        raise ValueError(f"kinds: one of {KINDS} per agent ({len(scene)}), got {kinds!r}")
    kept = np.zeros((0, 5)) if kept is None else np.asarray(kept, np.float64).reshape(-1, 5)
    _trajectories(img, cv, scene)   # under every box: the boxes are what must read
    _boxes(img, cv, kept, [KIND_COLOURS["kept"]] * len(kept))
    _boxes(img, cv, scene.boxes, [KIND_COLOURS[k] for k in kinds])
    token_xy = None if token_xy is None else np.asarray(token_xy, np.float64).reshape(-1, 2)
    if token_xy is not None and len(token_xy):
        radius = round(4.0 / cv.cfg.metres_per_pixel) << _SHIFT
        for p in cv.px(token_xy):
            cv2.circle(img, tuple(p), radius, TOKEN, max(2, round(2 * cv.u)), cv2.LINE_AA, _SHIFT)
    if ego is not None:
        _ego(img, cv, scene.boxes[int(ego), :2] if np.ndim(ego) == 0 else ego)
    if legend:
        shown = [k for k in KINDS if k == "generated" or k in kinds or (k == "kept" and len(kept))]
        _legend(img, cv, shown, token_xy is not None and len(token_xy) > 0, ego is not None, shown_lights)
        _scale_bar(img, cv)
        _north_arrow(img, cv)
    if title:
        _title(img, title, cv.u, reserve=round(40 * cv.u) if legend else 0)
    return img


# ---- contact sheets ------------------------------------------------------------------------------

def contact_sheet(rows: Sequence[Sequence[np.ndarray]], gap: int = 4) -> np.ndarray:
    """Tile images into a grid with white gaps (cells as large as the largest image)."""
    h = max(img.shape[0] for r in rows for img in r)
    w = max(img.shape[1] for r in rows for img in r)
    ncol = max(len(r) for r in rows)
    sheet = np.full((len(rows) * (h + gap) - gap, ncol * (w + gap) - gap, 3), 255, np.uint8)
    for r, row in enumerate(rows):
        for c, img in enumerate(row):
            y, x = r * (h + gap), c * (w + gap)
            sheet[y:y + img.shape[0], x:x + img.shape[1]] = img
    return sheet


def paginate(items: Sequence, per_page: int) -> list[list]:
    """``items`` in pages of at most ``per_page``, in order."""
    if per_page < 1:
        raise ValueError(f"per_page must be >= 1, got {per_page}")
    return [list(items[i:i + per_page]) for i in range(0, len(items), per_page)]


def captioned(img: np.ndarray, lines: Sequence[str], tile: int) -> np.ndarray:
    """``img`` scaled to ``tile`` px wide under a white band with ``lines`` of caption."""
    h, w = img.shape[:2]
    img = cv2.resize(img, (tile, max(1, round(h * tile / w))), interpolation=cv2.INTER_AREA)
    fs = 0.5 * tile / 400
    line = round(20 * tile / 400)
    band = np.full((line * len(lines) + 6, tile, 3), 255, np.uint8)
    for k, text in enumerate(lines):
        size = fs
        while size > 0.3 and cv2.getTextSize(text, _FONT, size, 1)[0][0] > tile - 8:
            size -= 0.02
        _text(band, text, (4, line * (k + 1) - 4), size)
    return np.vstack([band, img])


def contact_sheets(images: Sequence[np.ndarray], captions: Sequence[Sequence[str]] | None = None,
                   tile: int = 400, ncol: int = 4, per_page: int = 24, gap: int = 6) -> list[np.ndarray]:
    """Readable contact sheets: each image ``tile`` px wide with its caption lines above it,
    ``ncol`` to a row, ``per_page`` to a sheet. Returns one image per page."""
    if not images:
        return []
    captions = [[]] * len(images) if captions is None else list(captions)
    tiles = [captioned(img, cap, tile) for img, cap in zip(images, captions)]
    return [contact_sheet([page[i:i + ncol] for i in range(0, len(page), ncol)], gap)
            for page in paginate(tiles, per_page)]
