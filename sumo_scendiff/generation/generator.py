"""ScenarioGenerator: network + windows + tokens (+ seed) -> generated scenes, batched.

    gen = ScenarioGenerator.load()                       # the shipped checkpoint
    scenes = gen.generate(net, [Window(x, y, yaw)], seed=0)
    scenes = gen.generate(net, windows, tokens=[[{"x": 0, "y": 0, "heading": 0, "speed": 0}]], p_mask=0.5)

Pipeline per batch: map raster m -> initial noise (one generator per window, so a window's scene does
not depend on what else is in the batch) -> pinned tokens' latent cells (pinning.py) -> ODE from
sigma_max to 0 (DPM-Solver++(2M) by default) -> D(z, m) ->
boxes above ``threshold`` -> overlapping boxes removed (most probable kept) -> pinned tokens' agents
turned to the tokens' headings and paced to their speeds (pinning.turn_to_pins, pace_to_pins), the agents
of positioned partial tokens given what those tokens give (deliver.py) -> poses snapped onto
lane centre lines (lane_snap.py; agents on no lane removed unless a token asked for them, overlaps
removed again) -> with a requested density, the window's count round(density x car-lane km) kept: the
most probable boxes down to ``density_floor`` (trim_to_count), and where the model drew fewer, the
paper's infill with the scene so far pinned (infill.py) -> partial tokens no agent matched placed on
their lanes (deliver.place_rows) -> scene-frame :class:`~sumo_scendiff.core.scene.Scene` with speeds
from the trajectory.
"""
from __future__ import annotations

import os
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np
import shapely
import torch

from ..core.geometry import T0, TIMES, Window, box_corners
from ..core.matching import match_agents
from ..core.scene import Scene, speeds_from_traj, vclass_from_size
from ..map.raster import MAP_CHANNELS, RasterConfig, render_map
from ..model import checkpoint as ckpt
from ..model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from ..model.detection import decode_boxes
from ..model.diffusion import DiffusionConfig, ScenarioDiffusion
from ..tokens.encoding import (
    AGENT_TOKEN_DIM,
    GLOBAL_TOKEN_DIM,
    agent_tokens_from_dicts,
    global_token,
    pad_tokens,
    token_positions,
)
from ..tokens.features import is_pinnable
from ..tokens.raster import exact_values
from .config import GenerationConfig
from .deliver import apply_rows, delivered_rows, match_rows, missing_pins, pace_rows, place_rows
from .infill import add_new_agents, area_mask, in_area, scene_tokens
from .lane_heading import junction_yaw
from .lane_snap import snap_to_lanes
from .red_queues import stand_at_red
from .pinning import match_pins, pace_to_pins, pinned_latent, pinned_poses, turn_to_pins
from .token_resolve import resolve_tokens

DECIMALS = 3   # generated poses are rounded to mm / mrad
ASKED_RADIUS = 2.0  # m: a decoded agent this close to a token's position is what the token asked for
DEFAULT_CHECKPOINT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "weights", "scendiff.pt")


def remove_overlaps(boxes: np.ndarray, prob: np.ndarray) -> np.ndarray:
    """Indices of boxes kept when overlapping oriented boxes are removed, most probable first."""
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    order = np.argsort(-prob, kind="stable")
    corners = box_corners(boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3], boxes[:, 4])
    polys = shapely.polygons(corners)
    a, b = shapely.STRtree(polys).query(polys, predicate="intersects")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    overlaps: dict[int, list[int]] = {}
    for i, j in zip(a, b):
        if i != j and shapely.area(shapely.intersection(polys[i], polys[j])) > 1e-3:
            overlaps.setdefault(int(i), []).append(int(j))
    removed = np.zeros(len(boxes), bool)
    for i in order:
        if removed[i]:
            continue
        for j in overlaps.get(int(i), ()):
            if rank[j] > rank[i]:
                removed[j] = True
    return np.sort(np.flatnonzero(~removed))


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


class ScenarioGenerator:
    def __init__(self, autoencoder: ScenarioAutoencoder, diffusion: ScenarioDiffusion,
                 latent_scale: float, raster: RasterConfig = RasterConfig(), sha256: str = "",
                 config: GenerationConfig = GenerationConfig(), scene_guidance: float = 1.0,
                 scene_guidance_sigma: float = 0.0):
        # channels-last: oneDNN's faster convolution layout on CPU
        self.ae = autoencoder.eval().to(memory_format=torch.channels_last)
        self.diffusion = diffusion.eval().to(memory_format=torch.channels_last)
        self.latent_scale = latent_scale
        # the checkpoint's calibrated weight and interval (export --scene-guidance/--scene-guidance-sigma)
        self.scene_guidance, self.scene_guidance_sigma = scene_guidance, scene_guidance_sigma
        self.raster = raster
        self.sha256 = sha256
        self.config = config
        # the global token's guidance weight for windows given a density (None: scene_guidance's)
        self.density_guidance: float | None = None

    @classmethod
    def load(cls, path: str | None = None, config: GenerationConfig = GenerationConfig()):
        """Load a ``scenario-diffusion`` checkpoint (default: the shipped one)."""
        path = path or DEFAULT_CHECKPOINT
        ck = ckpt.load(path, "scenario-diffusion")
        try:
            unet = ck["diffusion_config"].get("unet", {})
            for field in ("pos_freqs", "splat_ch"):  # saved before these existed
                unet.setdefault(field, 0)
            ae = ScenarioAutoencoder(ckpt.config_from_dict(AutoencoderConfig, ck["autoencoder_config"]))
            df = ScenarioDiffusion(ckpt.config_from_dict(DiffusionConfig, ck["diffusion_config"]))
        except (KeyError, TypeError) as e:
            raise ckpt.CheckpointError(f"{path}: incomplete or incompatible checkpoint ({e})") from None
        ckpt.load_state(ae, {k: v.float() for k, v in ck["autoencoder"].items()}, path)
        ckpt.load_state(df, {k: v.float() for k, v in ck["diffusion"].items()}, path)
        gen = cls(ae, df, float(ck["latent_scale"]), sha256=ckpt.sha256(path), config=config,
                  scene_guidance=float(ck.get("scene_guidance", 1.0)),
                  scene_guidance_sigma=float(ck.get("scene_guidance_sigma", 0.0)))
        gen.density_guidance = ck.get("density_guidance")
        return gen


    @property
    def has_density(self) -> bool:
        """Whether the model takes the density condition (vehicles per km of car lane)."""
        return self.diffusion.cfg.unet.global_dim == GLOBAL_TOKEN_DIM

    def scene_guidance_for(self, cfg: GenerationConfig) -> float:
        """The global token's guidance weight a config generates with (None: the checkpoint's)."""
        return self.scene_guidance if cfg.scene_guidance is None else cfg.scene_guidance

    def scene_guidance_sigma_for(self, cfg: GenerationConfig) -> float:
        """The noise level below which that guidance stops (None: the checkpoint's)."""
        return self.scene_guidance_sigma if cfg.scene_guidance_sigma is None else cfg.scene_guidance_sigma

    def decode(self, z: torch.Tensor, m: torch.Tensor, tokens: torch.Tensor | None = None,
               pad: torch.Tensor | None = None, exact: torch.Tensor | None = None) -> torch.Tensor:
        """y = D(z / latent_scale, m[, the tokens' raster]): a decoder with ``C_t`` also reads the
        agent tokens (``tokens`` (B, T, AGENT_TOKEN_DIM) and ``pad`` from ``pad_tokens``; ``exact``:
        their exact speeds and turn, ``tokens.raster.exact_values``)."""
        t = self.ae.token_raster(tokens, pad, exact) if self.ae.cfg.C_t and tokens is not None else None
        return self.ae.decode(z / self.latent_scale, m, t)

    # ---- one batch ------------------------------------------------------------------------
    @torch.no_grad()
    def _batch(self, maps: np.ndarray, tokens: list[np.ndarray], p_mask: np.ndarray,
               seeds: list[int], cfg: GenerationConfig, pins: Sequence | None = None,
               net=None, windows: Sequence[Window] = (), density: np.ndarray | None = None):
        m = torch.from_numpy(maps).contiguous(memory_format=torch.channels_last)
        tok, pad = pad_tokens(tokens)
        glob = torch.from_numpy(global_token(p_mask, density, dim=self.diffusion.cfg.unet.global_dim)
                                .reshape(len(maps), -1))
        shape = (self.diffusion.cfg.unet.c_z, self.diffusion.cfg.unet.res, self.diffusion.cfg.unet.res)
        rngs = [torch.Generator().manual_seed(s) for s in seeds]
        noise = torch.stack([torch.randn(shape, generator=g) for g in rngs])

        def step_noise(sigma, sigma_next):   # a stochastic sampler's: each window from its own seed
            return torch.stack([torch.randn(shape, generator=g) for g in rngs])
        z = self.diffusion.sample(m, tok, pad, glob, steps=cfg.steps, sampler=cfg.solver(),
                                  noise=noise, noise_sampler=step_noise, guidance=cfg.guidance,
                                  local=cfg.local_guidance,
                                  signal_guidance=cfg.signal_guidance,
                                  scene_guidance=self.scene_guidance_for(cfg),
                                  scene_guidance_sigma=self.scene_guidance_sigma_for(cfg),
                                  density_guidance=self.density_guidance if cfg.scene_guidance is None
                                  else cfg.scene_guidance,
                                  known=pinned_latent(self.ae, pins, self.latent_scale, self.raster,
                                                      maps=m if cfg.pin_calibration else None)
                                  if cfg.pin_tokens and pins is not None else None)
        # a pinned token keeps its bins: its latent's speeds are calibrated to the decoder reading
        # the bins (pinning.calibrated_pins), and it is delivered at the token's speeds anyway
        skip = (lambda d: isinstance(d, Mapping) and is_pinnable(d)) if cfg.pin_tokens else None
        exact = exact_values(pins, [len(t) for t in tokens], skip) \
            if cfg.exact_token_values and pins is not None else None
        y = self.decode(z, m, tok, pad, exact)
        yaw = junction_yaw(y, windows, net, m[:, MAP_CHANNELS.index("junction")], self.raster.size) \
            if cfg.lane_headings and net is not None else None
        dec = decode_boxes(y, self.raster.size, yaw=yaw)
        return dec.prob.numpy(), dec.boxes.numpy(), dec.traj.numpy()

    def _scene(self, window: Window, prob, boxes, traj, cfg: GenerationConfig, net,
               tokens: np.ndarray | None = None, pins: np.ndarray | None = None,
               given: Sequence | None = None, count: int | None = None, floor: bool = False,
               area: tuple | None = None) -> Scene:
        # a requested count reaches below the threshold for boxes, and trims the most probable to it
        keep = select_boxes(window, prob, boxes, min(cfg.threshold, cfg.density_floor)
                            if count is not None or floor else cfg.threshold)
        boxes, traj = boxes[keep], traj[keep]
        turned = np.zeros(len(keep), bool)
        if cfg.pin_tokens and pins is not None and len(pins):
            boxes, traj, turned = turn_to_pins(boxes, traj, pins, ASKED_RADIUS)
            if cfg.pin_speeds:
                traj, _ = pace_to_pins(boxes, traj, pins, ASKED_RADIUS)
        # the positioned tokens not pinned: their agents take what they give (deliver.py)
        rows = delivered_rows(given) if cfg.deliver_tokens else np.zeros((0, 9))
        owner = np.full(len(keep), -1, np.int64)       # per agent: the delivered token's index
        paced = np.full((len(keep), 4), np.nan)          # per agent: its token's speeds and turn
        warnings: list[str] = []
        if len(rows):
            pinned = np.zeros(len(keep), bool)
            if cfg.pin_tokens and pins is not None and len(pins):
                pinned[[a for a, _ in match_pins(boxes, pins, ASKED_RADIUS)]] = True
            pairs = match_rows(boxes, rows, ASKED_RADIUS, taken=pinned)
            boxes, traj, told, paced = apply_rows(boxes, traj, rows, pairs)
            turned = turned | told
            for a, r in pairs:
                owner[a] = int(rows[r, 0])
        off_lane = 0
        if cfg.lane_snap and net is not None:
            boxes, traj, snapped = snap_to_lanes(boxes, traj, window, net, given=turned, exact=turned & (owner >= 0))
            # an agent on no car lane agreeing with it (off the road, or against a one-way street)
            # is one SUMO cannot take: removed, unless a token asked for a vehicle there
            asked = token_positions(tokens) if tokens is not None and len(tokens) else np.zeros((0, 2))
            near = (np.linalg.norm(boxes[:, None, :2] - asked[None], axis=-1) <= ASKED_RADIUS).any(1)
            ok = snapped[:, T0] | near
            off_lane = int((~ok).sum())
            # two boxes snapped onto one lane may now overlap, or a centre leave the window
            p, ok = prob[keep], np.flatnonzero(ok)
            ok = ok[remove_overlaps(boxes[ok], p[ok])]
            ok = ok[window.contains(boxes[ok, :2])]
            ok = ok[np.argsort(-p[ok], kind="stable")]
            keep, boxes, traj, owner, paced = keep[ok], boxes[ok], traj[ok], owner[ok], paced[ok]
            if cfg.pin_tokens and cfg.pin_speeds and pins is not None and len(pins):
                # snapping moved the poses onto the lanes, and so the steps: the token's speeds again
                traj, _ = pace_to_pins(boxes, traj, pins, ASKED_RADIUS, turn=False)
            if len(rows):
                traj, warnings = pace_rows(traj, paced, window, net, owner)
        if count is not None:
            mine = owner < 0
            if cfg.pin_tokens and pins is not None and len(pins):
                mine[[a for a, _ in match_pins(boxes, pins, ASKED_RADIUS)]] = False
            if not len(rows) and tokens is not None and len(tokens):
                # not delivered: the vehicle drawn for a positioned token is still the user's, never trimmed
                asked = token_positions(tokens)
                drawn, _ = match_agents(boxes[:, :3], np.c_[asked, np.full(len(asked), np.nan)], ASKED_RADIUS)
                mine[drawn] = False
            unplaced = len(rows) - int((owner >= 0).sum())     # tokens place_rows will still place
            ok = trim_to_count(prob[keep], mine, count - unplaced,
                               area_mask(window, boxes, area, net if cfg.count_on_edges else None),
                               area_mask(window, boxes, area))
            keep, boxes, traj, owner, paced = keep[ok], boxes[ok], traj[ok], owner[ok], paced[ok]
        score = np.round(prob[keep], 4).tolist()
        cell = keep.tolist()
        if cfg.deliver_tokens and cfg.pin_tokens:   # a pinned token no agent stands for is placed too
            rows = np.concatenate([rows, missing_pins(given, boxes, ASKED_RADIUS)])
        if len(rows) and net is not None:
            boxes, traj, owner, gone, placing = place_rows(boxes, traj, owner, rows, window, net)
            warnings = warnings + placing
            kept = [k for k in range(len(keep)) if k not in set(gone)]
            placed = len(owner) - len(kept)
            # a placed vehicle is the user's, not the model's: score 1, no latent cell
            score, cell = [score[k] for k in kept] + [1.0] * placed, [cell[k] for k in kept] + [-1] * placed
        # millimetres / milliradians: the float noise of batch composition and thread count
        # (~1e-6) must not make the same seed seed SUMO differently
        b, t = np.round(boxes, DECIMALS).astype(np.float32), np.round(traj, DECIMALS).astype(np.float32)
        mask = np.ones((len(b), len(TIMES)), bool)
        meta = {"score": score, "cell": cell, "off_lane_removed": off_lane}
        if len(rows):
            # per agent, the user token it delivers (None: the model's own); a tuple, not selected per agent
            meta["delivers"] = [int(o) if o >= 0 else None for o in owner]
            if warnings:
                meta["token_warnings"] = tuple(warnings)
        return Scene(window, b, t, mask, speeds_from_traj(t, mask), vclass_from_size(b[:, 3], b[:, 4]),
                     net.name, meta=meta)

    # ---- public API -----------------------------------------------------------------------
    def generate(self, net, windows: Sequence[Window], tokens=None, p_mask=1.0, seed: int = 0,
                 config: GenerationConfig | None = None, progress: bool = False,
                 maps: np.ndarray | None = None, noise_seeds: Sequence[int] | None = None,
                 density=None, signals=None, count_areas: Sequence | None = None) -> list[Scene]:
        """Scenes for ``windows`` on ``net``.

        ``tokens``: per window, agent tokens as a list of feature dicts (any subset of
        :data:`~sumo_scendiff.tokens.encoding.FEATURES`, scene frame of that window) or an encoded
        (T, 170) array; ``None`` for no tokens. A dict with pose, size and speed is pinned
        (:mod:`~sumo_scendiff.generation.pinning`) unless ``config.pin_tokens`` is False; a positioned
        one without them is delivered (:mod:`~sumo_scendiff.generation.deliver`) unless
        ``config.deliver_tokens`` is False; network references of token files (``edge``/``lane``/``pos``,
        ``ahead``/``lane_offset``) are resolved first (:mod:`.token_resolve`). ``p_mask``: the
        global scene token per window (or one for all); 1.0 with no tokens = map-only generation.
        The same ``seed`` gives the same scenes; window ``i`` uses the seed ``(seed, i)``. ``maps``: the windows' map rasters when
        already rendered (``render_map``), else rendered here. ``noise_seeds``: one seed per
        window instead (window ``i`` starts from the noise of ``noise_seeds[i]`` alone, whatever
        else is in the batch: the same seed with other tokens gives the variant of the same scene).
        ``density``: per window (or one for all) the vehicles per km of car lane the scene should
        hold, tokens' vehicles included; None or NaN: the model's own prior (needs a checkpoint with
        the density condition, :attr:`has_density`). Kept as a count (``config.match_density``):
        round(density x car-lane km). ``count_areas``: per window a world rectangle (x0, y0, x1, y1)
        or None, where that count is kept (the fill's tile cores); agents outside it are drawn as
        context and not counted.
        ``signals``: the traffic lights' states at the scene's time (tls id -> SUMO state string),
        one dict for all windows or one per window (``sim.lights.light_states``); None: unknown.
        Each scene keeps its window's in ``meta["signals"]``; given ``maps``, render those with the
        same states. Used with ``config.signals`` only; a model that predates the channels ignores them.
        """
        cfg = config or self.config
        n = len(windows)
        if tokens is not None and len(tokens) == n:
            # token-file references to the network (edge/lane/pos, ahead/lane_offset) made poses
            tokens = [resolve_tokens(net, w, t) for w, t in zip(windows, tokens)]
        toks = [_encode(t) for t in (tokens if tokens is not None else [None] * n)]
        if len(toks) != n:
            raise ValueError(f"{len(toks)} token sets for {n} windows")
        pm = np.broadcast_to(np.asarray(p_mask, np.float64), (n,))
        dens = None if density is None else np.broadcast_to(
            np.asarray([np.nan if d is None else d for d in np.atleast_1d(density)], np.float64), (n,))
        if noise_seeds is not None and len(noise_seeds) != n:
            raise ValueError(f"{len(noise_seeds)} noise seeds for {n} windows")
        keys = [[int(s)] for s in noise_seeds] if noise_seeds is not None else [[seed, i] for i in range(n)]
        seeds = [int(np.random.SeedSequence(k).generate_state(1)[0]) for k in keys]
        sig = (list(signals) if isinstance(signals, (list, tuple)) else signals) if cfg.signals else None
        if isinstance(sig, list) and len(sig) != n:
            raise ValueError(f"{len(sig)} signal states for {n} windows")
        areas = list(count_areas) if count_areas is not None else [None] * n
        if len(areas) != n:
            raise ValueError(f"{len(areas)} count areas for {n} windows")
        counts = [self._count(net, w, dens[k] if dens is not None else None, cfg, areas[k])
                  for k, w in enumerate(windows)]
        dens = self._condition(net, windows, dens)
        out: list[Scene] = []
        from tqdm import tqdm
        for s in tqdm(range(0, n, cfg.batch_size), disable=not progress, desc="generating"):
            sl = slice(s, min(n, s + cfg.batch_size))
            m = maps[sl] if maps is not None else np.stack([
                render_map(net, w, self.raster, signals=sig[k] if isinstance(sig, list) else sig)
                for k, w in enumerate(windows[sl], start=s)])
            prob, boxes, traj = self._batch(m, toks[sl], pm[sl], seeds[sl], cfg,
                                            tokens[sl] if tokens is not None else None,
                                            net=net, windows=windows[sl],
                                            density=None if dens is None else dens[sl])
            for k, w in enumerate(windows[sl], start=s):
                out.append(self._scene(w, prob[k - s], boxes[k - s], traj[k - s], cfg, net, toks[k],
                                       pinned_poses(tokens[k]) if tokens is not None else None,
                                       tokens[k] if tokens is not None else None,
                                       count=counts[k], area=areas[k]))
                if sig is not None:   # the lights this scene was drawn for, in scene.json and its picture
                    lights = sig[k] if isinstance(sig, list) else sig
                    ids = set(net.lights_in(w))
                    out[-1].meta["signals"] = {i: v for i, v in (lights or {}).items() if i in ids}
        for p in range(1, cfg.infill_passes + 1):
            short = [k for k, c in enumerate(counts) if c is not None and in_area(out[k], areas[k], net if cfg.count_on_edges else None).sum() < c]
            for s in range(0, len(short), cfg.batch_size):
                self._infill(net, windows, short[s:s + cfg.batch_size], out, counts, areas, tokens, toks,
                             seeds, dens, sig, cfg, p)
        if sig is not None and cfg.red_queues and net is not None:
            out = [stand_at_red(scene, net, sig[k] if isinstance(sig, list) else sig)
                   for k, scene in enumerate(out)]
        return out

    def _infill(self, net, windows, ks, out, counts, areas, tokens, toks, seeds, dens, sig, cfg, p):
        """One infill pass (generation/infill.py) over the windows ``ks`` short of their counts:
        drawn again with the scene so far pinned, from noise of their own (seed, pass)."""
        extra = [scene_tokens(out[k]) for k in ks]
        dicts = [[t for t in (tokens[k] if tokens is not None and tokens[k] is not None else ())
                  if isinstance(t, Mapping)] + e for k, e in zip(ks, extra)]
        toks2 = [np.concatenate([toks[k], agent_tokens_from_dicts(e)]) if e else toks[k] for k, e in zip(ks, extra)]
        maps = np.stack([render_map(net, windows[k], self.raster, signals=sig[k] if isinstance(sig, list) else sig)
                         for k in ks])
        # p_mask 1, "add what belongs here": the count is kept by trimming, and a lower p_mask
        # (the share the pins describe) under the tokens' guidance pushes towards adding nothing
        pm2 = np.ones(len(ks))
        seeds2 = [int(np.random.SeedSequence([seeds[k], p]).generate_state(1)[0]) for k in ks]
        # the pinned agents are context only (the first scene keeps its own): no pin calibration;
        # the guidance here is for adding vehicles around them, over the whole window and along the
        # estimate (local guidance fell short of the counts), the pins being fixed in the latent
        prob, boxes, traj = self._batch(maps, toks2, pm2, seeds2,
                                        replace(cfg, pin_calibration=False, local_guidance=False), dicts, net=net,
                                        windows=[windows[k] for k in ks], density=dens[ks])
        for i, k in enumerate(ks):
            # every candidate down to the floor: the first scene's redrawn agents are not new
            second = self._scene(windows[k], prob[i], boxes[i], traj[i], cfg, net, toks2[i],
                                 pinned_poses(dicts[i]), floor=True)
            taken = np.concatenate([out[k].boxes[:, :2], token_positions(toks[k]).reshape(-1, 2)])
            out[k] = add_new_agents(out[k], second, counts[k], taken, ASKED_RADIUS, areas[k],
                                    net if cfg.count_on_edges else None)

    @staticmethod
    def _condition(net, windows: Sequence[Window], dens: np.ndarray | None) -> np.ndarray | None:
        """Requested densities (per km of normal edges' car lanes, as SUMO's edgeData) in the model's
        unit, per km of every car lane of the window (:meth:`Network.condition_km`): the same
        vehicles, the condition the model was trained on."""
        if dens is None or net is None or not len(windows):
            return dens
        ratio = np.array([net.car_lane_km(w) / km if (km := net.condition_km(w)) > 0 else 1.0
                          for w in windows])
        return dens * ratio

    @staticmethod
    def _count(net, window: Window, density: float | None, cfg: GenerationConfig,
               area: tuple | None = None) -> int | None:
        """The vehicles a window (or its ``area``) holds at a requested density (None: no request,
        or not matched)."""
        if density is None or not np.isfinite(density) or not cfg.match_density or net is None:
            return None
        if area is None:
            return int(np.round(density * net.car_lane_km(window)))
        region = shapely.intersection(shapely.box(*area), shapely.box(*window.world_bounds()))
        return int(np.round(density * net.car_lane_km_in(region)))


def _encode(t) -> np.ndarray:
    if t is None:
        return np.zeros((0, AGENT_TOKEN_DIM), np.float32)
    if isinstance(t, np.ndarray) and t.ndim == 2 and t.shape[1] == AGENT_TOKEN_DIM:
        return t.astype(np.float32)
    return agent_tokens_from_dicts(list(t))
