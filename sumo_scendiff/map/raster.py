"""Bird's-eye-view rasters of a Window: the map image m and the agent image x (paper sec. 2.1, app. A).

    cfg = RasterConfig(pixels=128)
    m = render_map(net, window, cfg)                      # (len(MAP_CHANNELS), H, W) float32
    x = render_agents(boxes, traj, traj_mask, cfg)        # (len(AGENT_CHANNELS), H, W) float32

OpenCV does all drawing (sub-pixel precision via ``shift``); pixel coordinates come only from
:func:`sumo_scendiff.core.geometry.metres_to_pixels`.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..core.geometry import Window, box_corners, metres_to_pixels

# Lane directions as a histogram over LANE_DIR_BINS headings (window frame, bin k centred on
# k * 360 / LANE_DIR_BINS degrees, linear weights between the two nearest bins, the larger weight
# kept where lanes overlap). Unlike lane_cos / lane_sin, where the lane drawn last overwrites the
# others, crossing lanes inside a junction each keep their direction here.
LANE_DIR_BINS = 8
# Append-only: a model built for C_m channels reads the first C_m (older checkpoints: 11).
LANE_DIR_CHANNELS = tuple(f"lane_dir{k * 360 // LANE_DIR_BINS:03d}" for k in range(LANE_DIR_BINS))
MAP_CHANNELS = ("drivable", "centerline", "lane_cos", "lane_sin", "lane_boundary", "junction",
                "stop_line", "tls", "sidewalk", "crossing", "speed_limit") + LANE_DIR_CHANNELS + (
    "signal_go", "signal_stop")   # traffic-light states at t = 0 (map/signals.py); 0 where unknown
# Agent channels, paper appendix A: box fill, cos/sin of heading, then (mask, dx, dy) per delta.
DELTA_STEPS = (-2, -1, 1, 2)
AGENT_CHANNELS = ("occupancy", "cos", "sin") + tuple(
    f"{name}{t:+d}" for t in DELTA_STEPS for name in ("alpha", "dx", "dy"))
DELTA_SCALE = 30.0   # clip(delta / 30 + 0.5, 0, 1)
SPEED_SCALE = 30.0   # speed_limit channel = limit / 30 m/s
_SHIFT = 3           # OpenCV fixed-point bits: 1/8 pixel


@dataclass(frozen=True)
class RasterConfig:
    size: float = 100.0   # window side (m)
    pixels: int = 128     # H = W

    @property
    def shape(self) -> tuple[int, int]:
        return (self.pixels, self.pixels)

    @property
    def metres_per_pixel(self) -> float:
        return self.size / self.pixels


def _px(window: Window, xy_world: np.ndarray, cfg: RasterConfig) -> np.ndarray:
    """World metres -> OpenCV fixed-point pixel coordinates (int32, shift = _SHIFT)."""
    pix = metres_to_pixels(window.world_to_scene(xy_world), cfg.size, cfg.shape)
    return np.round(pix * (1 << _SHIFT)).astype(np.int32)


def _px_many(window: Window, arrays: list[np.ndarray], cfg: RasterConfig) -> list[np.ndarray]:
    """:func:`_px` on many polylines at once (one transform, then split back)."""
    if not arrays:
        return []
    pix = _px(window, np.concatenate(arrays), cfg)
    return np.split(pix, np.cumsum([len(a) for a in arrays])[:-1])


def _fill(img: np.ndarray, pix: list[np.ndarray], value: float = 1.0) -> None:
    if pix:
        cv2.fillPoly(img, pix, value, cv2.LINE_8, _SHIFT)


def direction_bins(rel_yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S,) window-frame yaws -> the two nearest direction bins (S, 2) and their weights (S, 2),
    which sum to 1 and interpolate linearly: a single lane's yaw is recoverable exactly."""
    u = np.mod(rel_yaw, 2 * np.pi) * (LANE_DIR_BINS / (2 * np.pi))
    k0 = np.floor(u).astype(np.int64) % LANE_DIR_BINS
    f = (u - np.floor(u)).astype(np.float32)
    return np.stack([k0, (k0 + 1) % LANE_DIR_BINS], 1), np.stack([1 - f, f], 1)


def _draw_direction_histogram(ch: dict, segments: list, rel_yaw: np.ndarray, thickness: np.ndarray) -> None:
    """Each segment (a, b) drawn ``thickness`` px wide into its two direction bins with its weight;
    within a bin, segments are drawn lightest first so that overlaps keep the larger weight."""
    bins, weights = direction_bins(rel_yaw)
    thick = thickness.astype(np.int64).tolist()
    for k in range(LANE_DIR_BINS):
        seg, side = np.nonzero((bins == k) & (weights > 0))
        w = weights[seg, side]
        order = np.argsort(w, kind="stable")
        img = ch[LANE_DIR_CHANNELS[k]]
        for i, value in zip(seg[order].tolist(), w[order].tolist()):
            a, b = segments[i]
            cv2.line(img, a, b, value, thick[i], cv2.LINE_8, _SHIFT)


def _draw_signals(ch: dict, net, window: Window, states: dict[str, str], cfg: RasterConfig) -> None:
    """Each controlled link's go/stop value on its via lane and its incoming lane's approach."""
    from .signals import approach, link_values
    idx = net.signal_links_in(window)
    if not idx or not states:
        return
    links = [net.signal_links[k] for k in idx]
    go, stop = link_values(links, states)
    lines = [approach(net.lanes[ln.lane].shape) for ln in links]
    # a via lane whose polygon is empty (a zero-length internal lane: berlin_doerpfeldstr has some)
    # has nothing to fill
    vias = [net.lanes[ln.via].ring if ln.via >= 0 and len(net.lanes[ln.via].ring) >= 3 else None
            for ln in links]
    pix = _px_many(window, lines + [v for v in vias if v is not None], cfg)
    line_pix, via_pix = pix[: len(links)], iter(pix[len(links):])
    via_pix = [next(via_pix) if v is not None else None for v in vias]
    for name, values in (("signal_go", go), ("signal_stop", stop)):
        img = ch[name]
        for k in np.argsort(values, kind="stable"):   # weakest first: the stronger state wins overlaps
            if values[k] <= 0:
                continue
            width = max(int(round(net.lanes[links[k].lane].width / cfg.metres_per_pixel)), 1)
            cv2.polylines(img, [line_pix[k]], False, float(values[k]), width, cv2.LINE_8, _SHIFT)
            if via_pix[k] is not None:
                cv2.fillPoly(img, [via_pix[k]], float(values[k]), cv2.LINE_8, _SHIFT)


def render_map(net, window: Window, cfg: RasterConfig = RasterConfig(),
               signals: dict[str, str] | None = None) -> np.ndarray:
    """The map image m of ``window``: channels :data:`MAP_CHANNELS`, float32 in [-1, 1].

    ``signals``: traffic-light states (tls id -> SUMO state string) at the scene's t = 0; without
    them the signal channels are 0, which the model reads as "unknown"."""
    h, w = cfg.shape
    ch = {name: np.zeros((h, w), np.float32) for name in MAP_CHANNELS}
    lanes = [net.lanes[i] for i in net.lanes_in(window)]
    junctions = [net.junctions[i] for i in net.junctions_in(window)]
    car = sorted((ln for ln in lanes if ln.car), key=lambda ln: ln.internal)  # internal lanes on top
    rings = dict(zip([id(ln) for ln in lanes] + [id(j) for j in junctions],
                     _px_many(window, [ln.ring for ln in lanes] + [j.ring for j in junctions], cfg)))

    j_rings = [rings[id(j)] for j in junctions]
    _fill(ch["junction"], j_rings)
    _fill(ch["drivable"], [rings[id(ln)] for ln in car] + j_rings)
    _fill(ch["tls"], [rings[id(ln)] for ln in car if ln.tls])
    _fill(ch["sidewalk"], [rings[id(ln)] for ln in lanes
                           if ln.pedestrian_only and ln.function != "crossing"])
    _fill(ch["crossing"], [rings[id(ln)] for ln in lanes if ln.function == "crossing"])
    for speed in sorted({ln.speed for ln in car}):  # slow first: the faster lane wins overlaps
        _fill(ch["speed_limit"], [rings[id(ln)] for ln in car if ln.speed == speed],
              min(speed / SPEED_SCALE, 1.0))
    bound = [rings[id(ln)] for ln in car if not ln.internal]
    if bound:
        cv2.polylines(ch["lane_boundary"], bound, True, 1.0, 1, cv2.LINE_8, _SHIFT)

    # centre lines coloured by direction: one 3-channel image (presence, cos, sin), segment by segment
    centre = np.zeros((h, w, 3), np.float32)
    stops = [ln for ln in car if ln.stop_line and not ln.internal and len(ln.shape) > 1]
    ends = []
    for ln in stops:
        d = ln.shape[-1] - ln.shape[-2]
        n = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-9) * 0.5 * ln.width
        ends.append(np.stack([ln.shape[-1] + n, ln.shape[-1] - n]))
    pix = _px_many(window, [ln.shape for ln in car] + ends, cfg)
    if car:
        rel = np.concatenate([ln.seg_yaw for ln in car]) - window.yaw
        colours = np.stack([np.ones_like(rel), np.cos(rel), np.sin(rel)], axis=1).tolist()
        segments = [(a, b) for pts in (p.tolist() for p in pix[: len(car)]) for a, b in zip(pts[:-1], pts[1:])]
        for (a, b), colour in zip(segments, colours):
            cv2.line(centre, a, b, colour, 2, cv2.LINE_8, _SHIFT)
        width = np.concatenate([np.full(len(ln.seg_yaw), ln.width) for ln in car])
        _draw_direction_histogram(ch, segments, rel, np.maximum(np.round(width / cfg.metres_per_pixel), 1))
    for a, b in pix[len(car):]:
        cv2.line(ch["stop_line"], tuple(a.tolist()), tuple(b.tolist()), 1.0, 2, cv2.LINE_8, _SHIFT)
    ch["centerline"], ch["lane_cos"], ch["lane_sin"] = centre[..., 0], centre[..., 1], centre[..., 2]
    if signals:
        _draw_signals(ch, net, window, signals, cfg)
    return np.stack([ch[name] for name in MAP_CHANNELS])


def agent_deltas(traj: np.ndarray, traj_mask: np.ndarray):
    """Paper eq. (app. A): position deltas and masks for the steps -2, -1, +1, +2.

    Returns (N, 4, 2) deltas and (N, 4) masks: D-2 = p-1 - p-2, D-1 = p0 - p-1, D1 = p1 - p0, D2 = p2 - p1.
    """
    p, m = traj[..., :2], traj_mask
    pairs = ((1, 0), (2, 1), (3, 2), (4, 3))  # (later, earlier) indices into TIMES
    delta = np.stack([p[:, a] - p[:, b] for a, b in pairs], axis=1)
    mask = np.stack([m[:, a] & m[:, b] for a, b in pairs], axis=1)
    return delta, mask


def render_agents(boxes: np.ndarray, traj: np.ndarray, traj_mask: np.ndarray,
                  cfg: RasterConfig = RasterConfig()) -> np.ndarray:
    """The agent image x: channels :data:`AGENT_CHANNELS` from scene-frame boxes and trajectories."""
    h, w = cfg.shape
    out = np.zeros((len(AGENT_CHANNELS), h, w), np.float32)
    n = len(boxes)
    if n == 0:
        return out
    delta, mask = agent_deltas(traj, traj_mask)
    values = np.zeros((n, len(AGENT_CHANNELS)), np.float32)
    values[:, 0] = 1.0
    values[:, 1], values[:, 2] = np.cos(boxes[:, 2]), np.sin(boxes[:, 2])
    scaled = np.clip(delta / DELTA_SCALE + 0.5, 0.0, 1.0) * mask[..., None]
    values[:, 3:] = np.concatenate([mask[..., None], scaled], axis=-1).reshape(n, -1)
    # one label image: each box filled with its index + 1, then every channel gathered at once
    label = np.zeros((h, w), np.float32)
    corners = box_corners(boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3], boxes[:, 4])
    pix = np.round(metres_to_pixels(corners, cfg.size, cfg.shape) * (1 << _SHIFT)).astype(np.int32)
    for i in range(n):
        cv2.fillPoly(label, [pix[i]], float(i + 1), cv2.LINE_8, _SHIFT)
    idx = label.astype(np.int64)
    hit = idx > 0
    out[:, hit] = values[idx[hit] - 1].T
    return out

