"""Pinned tokens: a token that fixes an agent's pose, size and speed is imposed in the latent.

    known = pinned_latent(ae, [[{"x": 10, "y": -1.6, "heading": 0, "length": 4.5, "width": 1.8,
                                 "speed": 8}]], latent_scale)
    z = diffusion.sample(m, tok, pad, glob, known=known)     # the agent is where the token says

The paper conditions on tokens only (cross-attention), and on this CPU-sized model a token's agent
is not always generated where the token says (docs/evaluation.md, "Token control"). A token that gives
position, heading, length, width and speed describes the agent completely enough to draw it: its
trajectory is synthesised (:func:`token_trajectories`: constant acceleration from ``speed`` to
``final_speed``, a circular arc whose chord turns by ``heading_to_final``, the past at the same
acceleration, never backwards), the token agents alone are rendered to the agent raster and encoded
by the autoencoder's E, and the latent cells they change (their *footprint*: the largest channel of
|mu(tokens) - mu(empty)| above :data:`FOOTPRINT`) are fixed to that latent while the diffusion model
generates the rest around them (:func:`~sumo_scendiff.model.edm.inpainted`). The decoder then finds
each pinned agent about as the autoencoder reconstructs it (docs/model.md, pinned tokens).
Tokens missing any of those features stay conditions only. A generated agent that would share a latent cell
(6.25 m) with a pinned one is not drawn there: the cell holds the pinned agent alone. After
decoding, the agent found within 2 m of a pinned token takes the token's heading
(:func:`turn_to_pins`): inside a junction the decoder's heading is its least certain output; and it
moves along its decoded path at the token's speed and final speed, turning by its
``heading_to_final`` where given (:func:`pace_to_pins`): the decoder shrinks speeds toward the
typical, never draws a stop and does not follow a token's turn.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import torch

from ..core.geometry import T0, TIMES, wrap_angle
from ..core.matching import assign
from ..core.scene import speeds_from_traj
from ..map.raster import RasterConfig, render_agents
from ..tokens.features import SEEDING_KEYS, is_pinnable

# |delta mu| (autoencoder units) above which a latent cell belongs to a pinned agent: 3-4 cells per
# agent. At 0.3 (12-19 cells) the pins crowd out the generated agents around them; at 2.5 (1 cell)
# they no longer hold (docs/model.md, pinned tokens)
FOOTPRINT = 1.0


def _distance(v0: float, a: float, t: np.ndarray) -> np.ndarray:
    """Signed distance from t = 0 at the integer time stamps ``t``, in SUMO's 1-s Euler update (a
    step moves a vehicle by its new speed, ``p(t) - p(t-1) = v(t)``), at speed ``v(t) = v0 + a t``
    clipped at 0 (standing, never backwards)."""
    def speed(k: int) -> float:
        return max(v0 + a * k, 0.0)
    # ahead: + v(1) + ... + v(t); behind: - v(t + 1) - ... - v(0)
    return np.array([sum(map(speed, range(1, ti + 1))) - sum(map(speed, range(ti + 1, 1)))
                     for ti in np.rint(np.asarray(t, np.float64)).astype(np.int64).tolist()], np.float64)


def token_trajectories(tokens: Sequence[Mapping]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scene-frame ``(boxes (N, 5), traj (N, 5, 3), traj_mask (N, 5))`` of pinnable token dicts.

    ``final_speed`` defaults to ``speed``, ``heading_to_final`` to 0 (straight). The turn is a
    circular arc over the 0...+2 s path whose chord leaves at ``heading_to_final`` to the heading, so
    the heading at +2 s is the heading plus twice that; the past is straight.
    """
    n = len(tokens)
    boxes = np.zeros((n, 5))
    traj = np.zeros((n, len(TIMES), 3))
    t = np.asarray(TIMES)
    for i, tok in enumerate(tokens):
        f = {k: float(v) for k, v in tok.items() if v is not None and k not in SEEDING_KEYS}
        x, y, h, v0 = f["x"], f["y"], f["heading"], f["speed"]
        v2 = _final_speed(tok)
        alpha = f.get("heading_to_final", 0.0)
        alpha = 0.0 if not np.isfinite(alpha) else alpha
        traj[i] = _arc(x, y, h, _distance(v0, (v2 - v0) / 2.0, t), alpha, t)
        boxes[i] = (x, y, h, f["length"], f["width"])
    assert np.allclose(traj[:, T0, :2], boxes[:, :2])
    return boxes, traj, np.ones((n, len(TIMES)), bool)


def _arc(x: float, y: float, h: float, s: np.ndarray, alpha: float, t: np.ndarray) -> np.ndarray:
    """(T, 3) poses at arc lengths ``s`` from the pose (x, y, h): straight for t <= 0, for t > 0 a
    circular arc whose chord to the last pose leaves at ``alpha`` to ``h`` (so it ends at h + 2 alpha)."""
    kappa = 2.0 * alpha / s[-1] if s[-1] > 1e-6 else 0.0            # curvature of the future arc
    k = np.where(t > 0, kappa, 0.0)
    theta = k * s                                                    # heading change along the path
    safe = np.abs(k) > 1e-9
    fwd = np.where(safe, np.sin(theta) / np.where(safe, k, 1.0), s)
    left = np.where(safe, (1.0 - np.cos(theta)) / np.where(safe, k, 1.0), 0.0)
    c, sn = np.cos(h), np.sin(h)
    return np.stack([x + c * fwd - sn * left, y + sn * fwd + c * left, wrap_angle(h + theta)], axis=1)


# Pin calibration: offsets (m/s) tried for the drawn speed, then for the drawn final speed, of pins
# asked to move at least MOVING m/s. Not the length, nor standing pins: calibrating those moved the
# decoded boxes off their tokens (docs/model.md, pinned tokens)
SPEED_OFFSETS = (-1.0, 0.0, 1.0, 2.0, 3.0, 4.0)
MOVING = 0.5
CALIBRATION_RADIUS = 2.0   # m: the decoded agent within this of a pin is the pin's
_CALIBRATED = ("speed", "final_speed")                     # in this order
_JUDGED = ("speed", "final_speed", "length")               # what the decoding is judged on


def _pins(tokens) -> list[list[dict]]:
    return [[dict(t) for t in (toks or []) if isinstance(t, Mapping) and is_pinnable(t)]
            if not isinstance(toks, np.ndarray) else [] for toks in tokens]


def _final_speed(token: Mapping) -> float:
    """A pinnable token's final speed; absent, its speed (as :func:`token_trajectories` draws it)."""
    v = token.get("final_speed")
    return float(token["speed"]) if v is None or not np.isfinite(float(v)) else float(v)


def _encode(autoencoder, pins: list[list[dict]], raster: RasterConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """mu of the pins drawn alone, one window per list, and mu of the empty window."""
    x = np.stack([render_agents(*token_trajectories(p), raster) for p in pins])  # [] renders empty
    mu = autoencoder.encode(torch.from_numpy(np.concatenate([x, np.zeros_like(x[:1])])))[0]
    return mu[:-1], mu[-1:]


def _decode_pins(autoencoder, mu: torch.Tensor, maps: torch.Tensor, pins: list[list[dict]],
                 size: float) -> np.ndarray:
    """(len(pins), max pins, 3) speed, final speed (SUMO's 1-s steps) and length of the most
    probable decoded box within :data:`CALIBRATION_RADIUS` of each pin; NaN where none is."""
    from ..model.detection import decode_boxes
    dec = decode_boxes(autoencoder.decode(mu, maps), size)
    prob, boxes, traj = dec.prob.numpy(), dec.boxes.numpy(), dec.traj.numpy()
    out = np.full((len(pins), max(map(len, pins)), 3), np.nan)
    for b, window in enumerate(pins):
        for j, t in enumerate(window):
            d = np.hypot(boxes[b, :, 0] - float(t["x"]), boxes[b, :, 1] - float(t["y"]))
            near = np.flatnonzero((d <= CALIBRATION_RADIUS) & (prob[b] >= 0.5))
            if len(near):
                k = near[np.argmax(prob[b, near])]
                v = speeds_from_traj(traj[b, k][None], np.ones((1, len(TIMES)), bool))[0]
                out[b, j] = v[T0], v[-1], boxes[b, k, 3]
    return out


def _footprint(mu: torch.Tensor, empty: torch.Tensor, footprint: float) -> torch.Tensor:
    """(B, 1, R, R): 1 on the latent cells the pins change by more than ``footprint``."""
    return ((mu - empty).abs().amax(dim=1, keepdim=True) > footprint).to(mu.dtype)


def calibrated_pins(autoencoder, maps: torch.Tensor, pins: list[list[dict]],
                    raster: RasterConfig = RasterConfig(), footprint: float = FOOTPRINT) -> list[list[dict]]:
    """The pins as they must be drawn for D(E(x), m) to decode the speeds they ask.

    The autoencoder shrinks what it draws toward the typical, and not linearly (README, "The
    model", pin calibration): a slow truck decodes much slower than drawn. So every pin
    asked to move (:data:`MOVING`) is drawn at each of :data:`SPEED_OFFSETS` added to its speed (all
    pins of a window at once, one copy of the window per offset), each copy is encoded and decoded
    on the window's map ``maps`` (B, C, H, W) from its footprint cells alone (the rest of the latent
    as in an empty window), and each pin keeps the offset whose decoding is nearest what it asks
    (speed, final speed and length together: they share latent cells, so drawing one differently
    moves the others); then the same with offsets to its final speed. The decoder still draws the
    agent; the latent is chosen so that it draws what the token asks. Costs 12 encodes and decodes
    of each window with pins."""
    want = np.array([[[float(t[f]) if f != "final_speed" else _final_speed(t) for f in _JUDGED] for t in w]
                     + [[np.nan] * len(_JUDGED)] * (max(map(len, pins)) - len(w)) for w in pins])
    moving = want[..., 0] >= MOVING                                          # (B, P); padding: False
    drawn = [[dict(t, final_speed=_final_speed(t)) for t in w] for w in pins]
    for feature in _CALIBRATED:
        copies = [[_shifted(t, feature, off) for t in w] for off in SPEED_OFFSETS for w in drawn]
        mu, empty = _encode(autoencoder, copies, raster)
        # as the diffusion model will hold them: the footprint cells pinned, the rest not the pins'
        z = torch.lerp(empty.expand_as(mu), mu, _footprint(mu, empty, footprint))
        got = _decode_pins(autoencoder, z, maps.repeat(len(SPEED_OFFSETS), 1, 1, 1), copies, raster.size)
        err = np.abs(got.reshape(len(SPEED_OFFSETS), len(pins), -1, len(_JUDGED)) - want[None]).sum(-1)
        best = np.argmin(np.where(np.isnan(err), np.inf, err), axis=0)      # (B, P)
        # not found, or standing: as asked
        best = np.where(np.isnan(err).all(axis=0) | ~moving, SPEED_OFFSETS.index(0.0), best)
        drawn = [[copies[best[b, j] * len(pins) + b][j] for j in range(len(w))] for b, w in enumerate(drawn)]
    return drawn


def _shifted(token: dict, feature: str, offset: float) -> dict:
    """``token`` with ``offset`` added to the speed ``feature`` (never below 0)."""
    return dict(token, **{feature: max(float(token[feature]) + offset, 0.0)})


@torch.no_grad()
def pinned_latent(autoencoder, tokens: Sequence[Sequence[Mapping] | None], latent_scale: float,
                  raster: RasterConfig = RasterConfig(), footprint: float = FOOTPRINT,
                  maps: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor] | None:
    """``(z_known, mask)`` for a batch of token lists (dicts; anything else pins nothing), in the
    diffusion model's scaled latent units, or None when no token of the batch is pinnable.
    ``mask`` (B, 1, R, R) is 1 on the cells of pinned agents, 0 elsewhere. With the windows'
    ``maps``, the pins are drawn as :func:`calibrated_pins` finds they must be."""
    pins = _pins(tokens)
    if not any(pins):
        return None
    if maps is not None:
        pins = calibrated_pins(autoencoder, maps, pins, raster, footprint)
    mu, empty = _encode(autoencoder, pins, raster)
    return mu * latent_scale, _footprint(mu, empty, footprint)


def pinned_poses(tokens: Sequence[Mapping] | None) -> np.ndarray:
    """(P, 6) scene-frame ``x, y, heading, speed, final_speed, heading_to_final`` of the pinnable
    token dicts of one window; the last two NaN where the token does not give them."""
    pins = [t for t in (tokens or ()) if isinstance(t, Mapping) and is_pinnable(t)]

    def given(t: Mapping, f: str) -> float:
        v = t.get(f)
        return np.nan if v is None or not np.isfinite(float(v)) else float(v)
    return np.array([[float(t["x"]), float(t["y"]), float(t["heading"]), float(t["speed"]),
                      given(t, "final_speed"), given(t, "heading_to_final")] for t in pins],
                    np.float64).reshape(-1, 6)


def match_pins(boxes: np.ndarray, pins: np.ndarray, radius: float) -> list[tuple[int, int]]:
    """(agent, pin) pairs: decoded boxes (N, 5) matched one-to-one to pins (P, >= 2) by centre
    distance within ``radius`` m (scipy's Hungarian)."""
    if len(boxes) == 0 or len(pins) == 0:
        return []
    d = np.linalg.norm(np.asarray(boxes)[:, None, :2] - np.asarray(pins)[None, :, :2], axis=-1)
    rows, cols = assign(d, d <= radius)
    return [(int(a), int(p)) for a, p in zip(rows, cols)]


def turn_to_pins(boxes: np.ndarray, traj: np.ndarray, pins: np.ndarray, radius: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pinned token's agent takes the token's heading: the decoded agents (boxes (N, 5), traj
    (N, T, 3), scene frame) are matched to the pins ``(P, >= 3)``: x, y, heading) by
    :func:`match_pins`, and a matched agent's box and trajectory turn rigidly about its current pose
    by the difference. Inside a junction the decoder's heading is the least certain part of a pinned
    agent (docs/evaluation.md, "Token control"), and the token states it exactly.
    Returns new arrays and which agents turned (N,)."""
    boxes, traj = np.array(boxes, np.float64), np.array(traj, np.float64)
    turned = np.zeros(len(boxes), bool)
    for a, p in match_pins(boxes, pins, radius):
        delta = float(wrap_angle(pins[p, 2] - boxes[a, 2]))
        c, s = np.cos(delta), np.sin(delta)
        rel = traj[a, :, :2] - traj[a, T0, :2]
        traj[a, :, :2] = traj[a, T0, :2] + rel @ np.array([[c, s], [-s, c]])
        traj[a, :, 2] = wrap_angle(traj[a, :, 2] + delta)
        boxes[a, 2] = traj[a, T0, 2]
        turned[a] = True
    return boxes, traj, turned


def retime(path: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(T, 3) poses at signed arc lengths ``s`` (T,) from the current pose along ``path`` (T, 3), the
    poses at 1-s steps: positions interpolated along the polyline, headings along its arc length;
    beyond either end the path goes on straight along that end's heading (backwards behind it)."""
    xy, yaw = path[:, :2], np.unwrap(path[:, 2])
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    arc = arc - arc[T0]
    keep = np.concatenate([[True], seg > 1e-6])                   # repeated poses add no length
    arc, xy, yaw = arc[keep], xy[keep], yaw[keep]
    out = np.empty((len(s), 3))
    out[:, 2] = np.interp(s, arc, yaw)
    out[:, 0], out[:, 1] = np.interp(s, arc, xy[:, 0]), np.interp(s, arc, xy[:, 1])
    for end, beyond in ((0, s < arc[0]), (-1, s > arc[-1])):
        extra = (s[beyond] - arc[end])[:, None]
        out[beyond, :2] = xy[end] + extra * np.array([np.cos(yaw[end]), np.sin(yaw[end])])
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def pace_to_pins(boxes: np.ndarray, traj: np.ndarray, pins: np.ndarray, radius: float,
                 turn: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Each pinned token's agent moves at the token's speed and final speed along its decoded path,
    and turns as the token says where it says.

    ``pins`` (P, 6): x, y, heading, speed, final speed, heading to final (:func:`pinned_poses`; NaN:
    not given). The decoder shrinks speeds toward the typical (docs/model.md,
    pinned speeds; it never draws a stop) and draws the future from the map, not
    from a token's turn, while the token states them: a matched agent's poses are moved along its
    own path (:func:`retime`) to where SUMO's 1-s update at constant acceleration from ``speed`` to
    ``final_speed`` puts them (:func:`token_trajectories`' convention; no final speed: the decoded
    change of speed kept); with ``heading_to_final`` its future (t > 0) is the token's arc from its
    current pose instead (``turn``; False: the path as it is, e.g. again after lane snap moved its
    poses onto the lanes). The current pose stays the decoder's (and the pinned heading's).
    Returns new ``traj`` and which agents were paced (N,)."""
    traj = np.array(traj, np.float64)
    paced = np.zeros(len(traj), bool)
    t = np.asarray(TIMES)
    for a, p in match_pins(boxes, pins, radius):
        v0, v2 = float(pins[p, 3]), float(pins[p, 4])
        if not np.isfinite(v2):
            v = speeds_from_traj(traj[a][None], np.ones((1, len(t)), bool))[0]
            v2 = max(v0 + float(v[-1] - v[T0]), 0.0)
        s = _distance(v0, (v2 - v0) / 2.0, t)
        traj[a] = retime(traj[a], s)
        alpha = float(pins[p, 5]) if pins.shape[1] > 5 else np.nan
        if turn and np.isfinite(alpha):
            x, y, h = traj[a, T0]
            traj[a, t > 0] = _arc(x, y, h, s, alpha, t)[t > 0]
        paced[a] = True
    return traj, paced
