"""One window's scene from its decoded boxes: the passes after the model, in this order.

Boxes above ``threshold`` -> overlapping boxes removed (most probable kept) -> pinned tokens' agents
turned to the tokens' headings and paced to their speeds (pinning.turn_to_pins, pace_to_pins), the
agents of positioned partial tokens given what those tokens give (deliver.py) -> poses snapped onto
lane centre lines (lane_snap.py; agents on no lane removed unless a token asked for them, overlaps
removed again) -> with a requested density, the window's count round(density x car-lane km) kept: the
most probable boxes down to ``density_floor`` (trim_to_count) -> partial tokens no agent matched
placed on their lanes (deliver.place_rows) -> scene-frame :class:`~sumo_scendiff.core.scene.Scene`
with speeds from the trajectory. Where the model drew fewer than the count, the generator draws the
window again (infill.py) and these passes run on that drawing too.

No model here: its calls (rasters, noise, sampler, decoder) are generator.py's, and these passes see
only a window's decoded boxes, its tokens and the network.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
import shapely

from ..core.geometry import T0, TIMES, Window, box_corners
from ..core.matching import match_agents
from ..core.scene import VEHICLE_CLASSES, Scene, speeds_from_traj, vclass_from_size
from ..tokens.encoding import token_positions
from .config import GenerationConfig
from .deliver import apply_rows, delivered_rows, match_rows, missing_pins, pace_rows, place_rows
from .infill import area_mask
from .lane_snap import snap_to_lanes
from .pinning import match_pins, pace_to_pins, turn_to_pins

DECIMALS = 3   # generated poses are rounded to mm / mrad
ASKED_RADIUS = 2.0  # m: a decoded agent this close to a token's position is what the token asked for


def remove_overlaps(boxes: np.ndarray, prob: np.ndarray) -> np.ndarray:
    """Indices of boxes kept when overlapping oriented boxes are removed, most probable first."""
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    order = np.argsort(-prob, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    a, b = overlapping_pairs(boxes)
    removed = np.zeros(len(boxes), bool)
    # by the rank of the first box: a box's own removal is settled before it removes others
    for i, j in zip(*(x[np.argsort(rank[a], kind="stable")] for x in (a, b))):
        if not removed[i] and rank[j] > rank[i]:
            removed[j] = True
    return np.flatnonzero(~removed)


def overlapping_pairs(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every ordered pair (i, j), i != j, of oriented boxes (N, 5) sharing more than 1e-3 m^2 of area."""
    polys = shapely.polygons(box_corners(boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3], boxes[:, 4]))
    a, b = shapely.STRtree(polys).query(polys, predicate="intersects")
    a, b = a[a != b], b[a != b]
    big = shapely.area(shapely.intersection(polys[a], polys[b])) > 1e-3
    return a[big], b[big]


def select_boxes(window: Window, prob: np.ndarray, boxes: np.ndarray, threshold: float) -> np.ndarray:
    """Indices of the decoded boxes a scene keeps, most probable first: probability >= ``threshold``,
    centre inside ``window`` (scene frame), overlapping oriented boxes removed (most probable kept)."""
    keep = np.flatnonzero(prob >= threshold)
    keep = keep[window.contains(boxes[keep, :2])]
    keep = keep[remove_overlaps(boxes[keep], prob[keep])]
    return keep[np.argsort(-prob[keep], kind="stable")]


def trim_to_count(prob: np.ndarray, mine: np.ndarray, count: int, counted: np.ndarray | None = None,
                  inside: np.ndarray | None = None) -> np.ndarray:
    """Positions (ascending, so an order by probability is kept) of the agents a scene keeps to
    hold ``count`` vehicles: every agent a token asked for (``~mine``), then the model's own most
    probable until ``count`` of them count. ``inside``: the agents in the area the count is of (the
    others are all kept; None: every agent); ``counted``: those of them that count (None: all), the
    others kept only where more probable than the last one that counts."""
    inside = np.ones(len(prob), bool) if inside is None else np.asarray(inside, bool)
    counted = inside.copy() if counted is None else np.asarray(counted, bool) & inside
    others = np.flatnonzero(mine & inside)
    others = others[np.argsort(-prob[others], kind="stable")]
    room = max(0, count - int((~mine & counted).sum()))
    before = np.cumsum(counted[others]) - counted[others]   # counted agents kept before each one
    take = others[before < room]
    return np.sort(np.concatenate([np.flatnonzero(~mine | ~inside), take]))


@dataclass
class Draft:
    """One window's scene while the passes of :func:`build_scene` work on it: per agent,
    its decoded cell (``keep``, -1: placed for a token), probability, pose, trajectory, the delivered
    token it stands for (``owner``, -1: the model's own), the speeds and turn that token paced it to
    (``paced``, NaN: not paced) and whether a token gave its heading (``turned``)."""
    keep: np.ndarray
    prob: np.ndarray
    boxes: np.ndarray
    traj: np.ndarray
    owner: np.ndarray
    paced: np.ndarray
    turned: np.ndarray
    warnings: list = field(default_factory=list)
    off_lane: int = 0
    all_prob: np.ndarray | None = None     # every decoded cell's probability

    @classmethod
    def selected(cls, window: Window, prob, boxes, traj, threshold: float) -> "Draft":
        keep = select_boxes(window, prob, boxes, threshold)
        n = len(keep)
        return cls(keep, prob[keep], boxes[keep], traj[keep], np.full(n, -1, np.int64),
                   np.full((n, 4), np.nan), np.zeros(n, bool), all_prob=prob)

    def take(self, idx: np.ndarray) -> None:
        """Keep the agents ``idx`` (indices, in their new order)."""
        for name in ("keep", "prob", "boxes", "traj", "owner", "paced", "turned"):
            setattr(self, name, getattr(self, name)[idx])

    def pinned(self, pins: np.ndarray | None) -> np.ndarray:
        """Per agent, whether it stands for one of the pinned tokens ``pins``."""
        out = np.zeros(len(self.keep), bool)
        if pins is not None:
            out[[a for a, _ in match_pins(self.boxes, pins, ASKED_RADIUS)]] = True
        return out

    def scene(self, window: Window, net, delivering: bool) -> Scene:
        """The scene: poses to millimetres / milliradians (the float noise of batch composition and
        thread count, ~1e-6, must not make the same seed seed SUMO differently); a vehicle placed for
        a token is the user's, not the model's: score 1, no latent cell."""
        b, t = np.round(self.boxes, DECIMALS).astype(np.float32), np.round(self.traj, DECIMALS).astype(np.float32)
        mask = np.ones((len(b), len(TIMES)), bool)
        placed = self.keep < 0
        score = np.where(placed, 1.0, np.round(self.prob, 4)).tolist()
        meta = {"score": score, "cell": self.keep.tolist(), "off_lane_removed": self.off_lane}
        if delivering:
            # per agent, the user token it delivers (None: the model's own); a tuple, not selected per agent
            meta["delivers"] = [int(o) if o >= 0 else None for o in self.owner]
            if self.warnings:
                meta["token_warnings"] = tuple(self.warnings)
        return Scene(window, b, t, mask, speeds_from_traj(t, mask), vclass_from_size(b[:, 3], b[:, 4]),
                     net.name, meta=meta)


def _token_classes(scene: Scene, given: Sequence | None) -> Scene:
    """The agent standing for a positioned token that names a class (``vclass``) is of that class at
    the class's size (the token's length and width): the class read back from the drawn box
    (vclass_from_size) would miss it, the model drawing a bus token's box about a truck's length."""
    asked = [t for t in (given or ()) if isinstance(t, Mapping) and t.get("vclass") in VEHICLE_CLASSES
             and t.get("x") is not None and t.get("y") is not None]
    if not asked or not len(scene):
        return scene
    where = np.array([[float(t["x"]), float(t["y"])] for t in asked], np.float64)
    for a, k in match_pins(scene.boxes.astype(np.float64), where, ASKED_RADIUS):
        scene.vclass[a] = VEHICLE_CLASSES.index(asked[k]["vclass"])
        scene.boxes[a, 3:5] = float(asked[k]["length"]), float(asked[k]["width"])
    return scene


def _turn_pins(d: Draft, pins: np.ndarray, cfg: GenerationConfig) -> None:
    """Pinned tokens' agents turned to the tokens' headings and paced to their speeds (pinning.py)."""
    d.boxes, d.traj, d.turned = turn_to_pins(d.boxes, d.traj, pins, ASKED_RADIUS)
    if cfg.pin_speeds:
        d.traj, _ = pace_to_pins(d.boxes, d.traj, pins, ASKED_RADIUS)


def _deliver(d: Draft, rows: np.ndarray, pins: np.ndarray | None) -> None:
    """The agents matched to positioned partial tokens take what those give (deliver.py)."""
    pairs = match_rows(d.boxes, rows, ASKED_RADIUS, taken=d.pinned(pins))
    d.boxes, d.traj, told, d.paced = apply_rows(d.boxes, d.traj, rows, pairs)
    d.turned = d.turned | told
    for a, r in pairs:
        d.owner[a] = int(rows[r, 0])


def _snap(d: Draft, window: Window, net, tokens: np.ndarray | None, pins: np.ndarray | None,
          rows: np.ndarray) -> None:
    """Poses onto the lanes' centre lines (lane_snap.py). An agent on no car lane agreeing with it
    (off the road, or against a one-way street) is one SUMO cannot take: removed, unless a token asked
    for a vehicle there. Two boxes snapped onto one lane may now overlap, or a centre leave the
    window. Snapping moved the steps: pinned (``pins``) and delivered agents paced again."""
    d.boxes, d.traj, snapped = snap_to_lanes(d.boxes, d.traj, window, net, given=d.turned,
                                             exact=d.turned & (d.owner >= 0))
    asked = token_positions(tokens) if tokens is not None and len(tokens) else np.zeros((0, 2))
    near = (np.linalg.norm(d.boxes[:, None, :2] - asked[None], axis=-1) <= ASKED_RADIUS).any(1)
    ok = snapped[:, T0] | near
    d.off_lane = int((~ok).sum())
    ok = np.flatnonzero(ok)
    ok = ok[remove_overlaps(d.boxes[ok], d.prob[ok])]
    ok = ok[window.contains(d.boxes[ok, :2])]
    d.take(ok[np.argsort(-d.prob[ok], kind="stable")])
    if pins is not None:
        d.traj, _ = pace_to_pins(d.boxes, d.traj, pins, ASKED_RADIUS, turn=False)
    if len(rows):
        d.traj, d.warnings = pace_rows(d.traj, d.paced, window, net, d.owner)


def _trim(d: Draft, window: Window, net, tokens: np.ndarray | None, pins: np.ndarray | None,
          rows: np.ndarray, count: int, area: tuple | None, on_edges: bool) -> None:
    """The model's own agents trimmed to ``count`` (:func:`trim_to_count`); what a token asked for stays."""
    mine = (d.owner < 0) & ~d.pinned(pins)
    if not len(rows) and tokens is not None and len(tokens):
        # not delivered: the vehicle drawn for a positioned token is still the user's, never trimmed
        asked = token_positions(tokens)
        drawn, _ = match_agents(d.boxes[:, :3], np.c_[asked, np.full(len(asked), np.nan)], ASKED_RADIUS)
        mine[drawn] = False
    unplaced = len(rows) - int((d.owner >= 0).sum())     # tokens place_rows will still place
    d.take(trim_to_count(d.prob, mine, count - unplaced,
                         area_mask(window, d.boxes, area, net if on_edges else None),
                         area_mask(window, d.boxes, area)))


def _place(d: Draft, rows: np.ndarray, window: Window, net) -> None:
    """Tokens no agent stands for placed on their lanes (deliver.place_rows), the agents they
    overlap removed."""
    boxes, traj, owner, gone, placing = place_rows(d.boxes, d.traj, d.owner, rows, window, net)
    d.warnings = d.warnings + placing
    d.take(np.setdiff1d(np.arange(len(d.keep)), np.asarray(gone, np.int64)))
    added = len(owner) - len(d.keep)
    d.boxes, d.traj, d.owner = boxes, traj, owner
    d.keep = np.concatenate([d.keep, np.full(added, -1, np.int64)])
    d.prob = np.concatenate([d.prob, np.ones(added, d.prob.dtype)])
    d.paced = np.concatenate([d.paced, np.full((added, 4), np.nan)])
    d.turned = np.concatenate([d.turned, np.zeros(added, bool)])


def build_scene(window: Window, prob, boxes, traj, cfg: GenerationConfig, net,
                tokens: np.ndarray | None = None, pins: np.ndarray | None = None,
                given: Sequence | None = None, count: int | None = None, floor: bool = False,
                area: tuple | None = None) -> Scene:
    """One window's scene from its decoded boxes, the passes in the module docstring's order."""
    pins = pins if cfg.pin_tokens and pins is not None and len(pins) else None
    # a requested count reaches below the threshold for boxes, and trims the most probable to it
    d = Draft.selected(window, prob, boxes, traj, min(cfg.threshold, cfg.density_floor)
                       if count is not None or floor else cfg.threshold)
    if pins is not None:
        _turn_pins(d, pins, cfg)
    # the positioned tokens not pinned: their agents take what they give (deliver.py)
    rows = delivered_rows(given) if cfg.deliver_tokens else np.zeros((0, 9))
    if len(rows):
        _deliver(d, rows, pins)
    if cfg.lane_snap and net is not None:
        _snap(d, window, net, tokens, pins if cfg.pin_speeds else None, rows)
    if count is not None:
        _trim(d, window, net, tokens, pins, rows, count, area, cfg.count_on_edges)
    if cfg.deliver_tokens and cfg.pin_tokens:   # a pinned token no agent stands for is placed too
        rows = np.concatenate([rows, missing_pins(given, d.boxes, ASKED_RADIUS)])
    if len(rows) and net is not None:
        _place(d, rows, window, net)
    return _token_classes(d.scene(window, net, delivering=len(rows) > 0), given)
