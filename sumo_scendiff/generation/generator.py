"""ScenarioGenerator: network + windows + tokens (+ seed) -> generated scenes, batched.

    gen = ScenarioGenerator.load()                       # the shipped checkpoint
    scenes = gen.generate(net, [Window(x, y, yaw)], seed=0)
    scenes = gen.generate(net, windows, tokens=[[{"x": 0, "y": 0, "heading": 0, "speed": 0}]], p_mask=0.5)

Pipeline per batch: map raster m -> initial noise (one generator per window, so a window's scene does
not depend on what else is in the batch) -> pinned tokens' latent cells (pinning.py) -> ODE from
sigma_max to 0 (DPM-Solver++(2M) by default) -> D(z, m) -> decoded boxes -> each window's scene by the
passes of scene_passes.py (selection, pins, delivered tokens, lane snap, the requested count, placed
tokens) -> where a window holds fewer than a requested density's count, the paper's infill with the
scene so far pinned (infill.py) -> with the lights given, queues at red standing (red_queues.py).
"""
from __future__ import annotations

import os
import weakref
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np
import shapely
import torch

from ..core.geometry import Window
from ..core.scene import Scene, speeds_from_traj  # noqa: F401  (speeds_from_traj: imported from here)
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
from .infill import add_new_agents, in_area, scene_tokens
from .lane_heading import junction_yaw
from .pinning import pinned_latent, pinned_poses
from .red_queues import stand_at_red
# the passes that make a scene of decoded boxes; their public names are imported from here too
from .scene_passes import ASKED_RADIUS, build_scene, remove_overlaps, select_boxes, trim_to_count  # noqa: F401
from .token_resolve import resolve_tokens

# the models this process holds, by checkpoint file (real path, size, mtime): a generator loaded while
# another of the same file lives shares its model (the studio's runs); weak, so nobody else keeps one
_HELD: weakref.WeakValueDictionary = weakref.WeakValueDictionary()
DEFAULT_CHECKPOINT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "weights", "scendiff.pt")


# glibc's malloc hands a block above its mmap threshold (at most 32 MB, its dynamic ceiling) back to the
# kernel when freed, and the next tensor of that size faults every page in again: a batch's map encoders
# and decoder work on 30-60 MB activations, and spent about half their time in those faults (E_m 0.70 ->
# 0.34 s CPU for 32 windows, the decoder 0.99 -> 0.66 s, the same floats). Kept in the heap instead.
MMAP_THRESHOLD = 1 << 30
TRIM_THRESHOLD = 1 << 31


def keep_freed_memory() -> None:
    """Let this process's malloc reuse freed tensor memory instead of returning it to the kernel
    (glibc only; elsewhere nothing happens). Process-wide and idempotent."""
    import ctypes
    try:
        if "glibc" not in (os.confstr("CS_GNU_LIBC_VERSION") or "").lower():
            return
        libc = ctypes.CDLL(None)       # the symbols of this process: glibc's among them
        libc.mallopt(-3, MMAP_THRESHOLD)    # M_MMAP_THRESHOLD
        libc.mallopt(-1, TRIM_THRESHOLD)    # M_TRIM_THRESHOLD
    except (ValueError, OSError, AttributeError):   # no such name, no such library or function
        return


def _file_key(path: str) -> tuple | None:
    """What a checkpoint file must still be for a held model to be its own; None: no such file (the
    checkpoint's reader says so)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return os.path.realpath(path), st.st_size, st.st_mtime_ns


@dataclass(frozen=True, eq=False)
class _Model:
    """A checkpoint's modules and calibrated guidance, as read from its file."""
    ae: ScenarioAutoencoder
    diffusion: ScenarioDiffusion
    latent_scale: float
    sha256: str
    scene_guidance: float
    scene_guidance_sigma: float
    density_guidance: float | None


def _read_model(path: str) -> _Model:
    ck = ckpt.load(path, "scenario-diffusion")
    try:
        unet = ck["diffusion_config"].get("unet", {})
        for name in ("pos_freqs", "splat_ch"):  # saved before these existed
            unet.setdefault(name, 0)
        ae = ScenarioAutoencoder(ckpt.config_from_dict(AutoencoderConfig, ck["autoencoder_config"]))
        df = ScenarioDiffusion(ckpt.config_from_dict(DiffusionConfig, ck["diffusion_config"]))
    except (KeyError, TypeError) as e:
        raise ckpt.CheckpointError(f"{path}: incomplete or incompatible checkpoint ({e})") from None
    ckpt.load_state(ae, {k: v.float() for k, v in ck["autoencoder"].items()}, path)
    ckpt.load_state(df, {k: v.float() for k, v in ck["diffusion"].items()}, path)
    return _Model(ae, df, float(ck["latent_scale"]), ckpt.sha256(path), float(ck.get("scene_guidance", 1.0)),
                  float(ck.get("scene_guidance_sigma", 0.0)), ck.get("density_guidance"))


@dataclass
class Request:
    """:meth:`ScenarioGenerator.generate`'s inputs, one per window: the token dicts as given (road
    references resolved; None: no tokens), encoded, p_mask, the density as the model's condition
    (None: none), the noise seed, the lights' states (None: not used), the count's area and the count."""
    tokens: list | None
    toks: list
    p_mask: np.ndarray
    density: np.ndarray | None
    seeds: list
    lights: list | None
    areas: list
    counts: list

    def given(self, k: int):
        return self.tokens[k] if self.tokens is not None else None

    def light(self, k: int):
        return self.lights[k] if self.lights is not None else None


class ScenarioGenerator:
    def __init__(self, autoencoder: ScenarioAutoencoder, diffusion: ScenarioDiffusion,
                 latent_scale: float, raster: RasterConfig = RasterConfig(), sha256: str = "",
                 config: GenerationConfig = GenerationConfig(), scene_guidance: float = 1.0,
                 scene_guidance_sigma: float = 0.0):
        keep_freed_memory()
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
        """Load a ``scenario-diffusion`` checkpoint (default: the shipped one); while this process
        holds a generator of the same, unchanged file, that one's model."""
        path = path or DEFAULT_CHECKPOINT
        key = _file_key(path)
        model = _HELD.get(key) if key else None
        if model is None:
            model = _read_model(path)
            if key:
                _HELD[key] = model
        gen = cls(model.ae, model.diffusion, model.latent_scale, sha256=model.sha256, config=config,
                  scene_guidance=model.scene_guidance, scene_guidance_sigma=model.scene_guidance_sigma)
        gen.density_guidance = model.density_guidance
        gen.held_model = model    # keeps it held while this generator lives
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
        req = self._request(net, windows, tokens, p_mask, seed, cfg, noise_seeds, density, signals, count_areas)
        out = self._draw(net, windows, req, cfg, maps, progress)
        on_edges = net if cfg.count_on_edges else None
        for p in range(1, cfg.infill_passes + 1):
            short = [k for k, c in enumerate(req.counts)
                     if c is not None and in_area(out[k], req.areas[k], on_edges).sum() < c]
            for s in range(0, len(short), cfg.batch_size):
                self._infill(net, windows, short[s:s + cfg.batch_size], out, req, cfg, p)
        if req.lights is not None and cfg.red_queues and net is not None:
            out = [stand_at_red(scene, net, req.lights[k]) for k, scene in enumerate(out)]
        return out

    def _request(self, net, windows, tokens, p_mask, seed, cfg, noise_seeds, density, signals,
                 count_areas) -> Request:
        """:meth:`generate`'s arguments checked and made one per window."""
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
        return Request(tokens, toks, pm, self._condition(net, windows, dens), seeds,
                       None if sig is None else sig if isinstance(sig, list) else [sig] * n, areas, counts)

    def _draw(self, net, windows, req: Request, cfg: GenerationConfig, maps: np.ndarray | None,
              progress: bool) -> list[Scene]:
        """Every window's first scene, a batch of ``cfg.batch_size`` windows at a time."""
        out: list[Scene] = []
        from tqdm import tqdm
        for s in tqdm(range(0, len(windows), cfg.batch_size), disable=not progress, desc="generating"):
            ks = range(s, min(len(windows), s + cfg.batch_size))
            m = maps[s:ks.stop] if maps is not None else np.stack([
                render_map(net, windows[k], self.raster, signals=req.light(k)) for k in ks])
            prob, boxes, traj = self._batch(m, req.toks[s:ks.stop], req.p_mask[s:ks.stop], req.seeds[s:ks.stop],
                                            cfg, req.tokens[s:ks.stop] if req.tokens is not None else None,
                                            net=net, windows=windows[s:ks.stop],
                                            density=None if req.density is None else req.density[s:ks.stop])
            for i, k in enumerate(ks):
                given = req.given(k)
                out.append(build_scene(windows[k], prob[i], boxes[i], traj[i], cfg, net, req.toks[k],
                                       pinned_poses(given) if req.tokens is not None else None, given,
                                       count=req.counts[k], area=req.areas[k]))
                if req.lights is not None:   # the lights this scene was drawn for, in scene.json and its picture
                    ids = set(net.lights_in(windows[k]))
                    out[-1].meta["signals"] = {i: v for i, v in (req.light(k) or {}).items() if i in ids}
        return out

    def _infill(self, net, windows, ks, out: list[Scene], req: Request, cfg: GenerationConfig, p: int):
        """One infill pass (generation/infill.py) over the windows ``ks`` short of their counts:
        drawn again with the scene so far pinned, from noise of their own (seed, pass)."""
        extra = [scene_tokens(out[k]) for k in ks]
        dicts = [[t for t in (req.given(k) or ()) if isinstance(t, Mapping)] + e for k, e in zip(ks, extra)]
        toks2 = [np.concatenate([req.toks[k], agent_tokens_from_dicts(e)]) if e else req.toks[k]
                 for k, e in zip(ks, extra)]
        maps = np.stack([render_map(net, windows[k], self.raster, signals=req.light(k)) for k in ks])
        # p_mask 1, "add what belongs here": the count is kept by trimming, and a lower p_mask
        # (the share the pins describe) under the tokens' guidance pushes towards adding nothing
        pm2 = np.ones(len(ks))
        seeds2 = [int(np.random.SeedSequence([req.seeds[k], p]).generate_state(1)[0]) for k in ks]
        # the pinned agents are context only (the first scene keeps its own): no pin calibration;
        # the guidance here is for adding vehicles around them, over the whole window and along the
        # estimate (local guidance fell short of the counts), the pins being fixed in the latent
        prob, boxes, traj = self._batch(maps, toks2, pm2, seeds2,
                                        replace(cfg, pin_calibration=False, local_guidance=False), dicts, net=net,
                                        windows=[windows[k] for k in ks], density=req.density[ks])
        for i, k in enumerate(ks):
            # every candidate down to the floor: the first scene's redrawn agents are not new
            second = build_scene(windows[k], prob[i], boxes[i], traj[i], cfg, net, toks2[i],
                                 pinned_poses(dicts[i]), floor=True)
            taken = np.concatenate([out[k].boxes[:, :2], token_positions(req.toks[k]).reshape(-1, 2)])
            out[k] = add_new_agents(out[k], second, req.counts[k], taken, ASKED_RADIUS, req.areas[k],
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
