"""The two training stages: the detection autoencoder and the latent diffusion model in its latent space.

Each takes the parsed options of its ``train`` subcommand and runs
:class:`~sumo_scendiff.train.loop.Loop` until ``--steps``; bad input raises
:class:`~sumo_scendiff.train.loop.TrainError` (the CLI prints its one line and exits 2).
"""
from __future__ import annotations

import os
from dataclasses import asdict

import torch

from ..model import checkpoint as ckpt
from ..model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from ..model.diffusion import DiffusionConfig, ScenarioDiffusion
from ..tokens.masking import TokenMaskConfig
from ..tokens.raster import C_T
from .compiling import compile_diffusion_stage
from .config import TrainConfig
from .loop import Loop, TrainError, conditioning, estimate_latent_scale, load_training, rank
from .token_decoder import decoder_conditioning


def train_config(o, defaults: TrainConfig) -> TrainConfig:
    kw = {f: getattr(o, f) for f in asdict(defaults) if getattr(o, f, None) is not None}
    return TrainConfig(**{**asdict(defaults), **kw})


def token_mask_config(cfg: TrainConfig) -> TokenMaskConfig:
    """Which agents become tokens and which features they give, as a stage asks."""
    return TokenMaskConfig(p_keep_all_tokens=cfg.p_keep_all_tokens, p_map_only=cfg.p_map_only,
                           p_all_features=cfg.p_all_features, p_drop_group=cfg.p_drop_group)


def _merge(base: dict, over: dict) -> dict:
    return {k: (_merge(v, over[k]) if isinstance(v, dict) and isinstance(over.get(k), dict)
                else over.get(k, v)) for k, v in base.items()} | {k: v for k, v in over.items() if k not in base}


def model_config(o, cls, base: dict | None = None, **fixed):
    """The model config: ``base`` (a saved config) or the defaults, then ``fixed``, then
    ``--model-config`` overrides (nested dicts merge)."""
    merged = _merge({**base, **fixed} if base is not None else asdict(cls(**fixed)), o.model_config)
    try:
        return ckpt.config_from_dict(cls, merged)
    except (ckpt.CheckpointError, TypeError) as e:
        raise TrainError(f"--model-config: {e}") from None


def warm_start_record(init: dict, path: str) -> dict:
    """What a warm-started run keeps of its source: its SHA-256 and the steps behind it."""
    return {"init_from_sha256": ckpt.sha256(path), "steps_before": init["step"] + init.get("steps_before", 0)}


def adam(cls, params, **kw) -> torch.optim.Optimizer:
    """``cls`` (Adam, AdamW) in its fused form where this torch has one for the device: the same
    update to float rounding in a quarter of the CPU time (docs/training.md, "torch.compile")."""
    params = list(params)
    try:
        return cls(params, fused=True, **kw)
    except RuntimeError:   # torch before 2.4 fuses on CUDA only
        return cls(params, **kw)


# each stage's defaults: the shipped model's settings (docs/training.md)
AUTOENCODER_DEFAULTS = TrainConfig(steps=5500, lr=5e-4, weight_decay=1e-4, p_all_features=0.2, p_drop_group=0.5,
                                   p_mislead=0.7, p_counterfactual=0.5)
DIFFUSION_DEFAULTS = TrainConfig(steps=5000, batch_size=32, lr=6e-4, weight_decay=1e-5, ema_halflife=250.0,
                                 token_loss_weight=4.0, p_no_signals=0.3)


def _autoencoder_model(o, saved: dict | None, init: dict | None) -> ScenarioAutoencoder:
    """A run continues with its own config, a warm start with its source's (--model-config on top)."""
    base = (saved or init or {}).get("model_config")
    model = ScenarioAutoencoder(model_config(o, AutoencoderConfig, base=base,
                                             **({"use_map": False} if o.no_map else {})))
    if model.cfg.C_t not in (0, C_T):
        raise TrainError(f"--model-config: C_t {model.cfg.C_t}: the token raster has {C_T} channels "
                         f"(0: a decoder without tokens)")
    return model


def train_autoencoder(o) -> None:
    cfg = train_config(o, AUTOENCODER_DEFAULTS)
    last = os.path.join(o.out, "last.pt")
    saved = ckpt.load(last, "autoencoder-train") if os.path.exists(last) else None
    init = load_training(o.init_from, "autoencoder-train") if o.init_from and saved is None else None
    model = _autoencoder_model(o, saved, init)
    extra = {"model_config": ckpt.config_to_dict(model.cfg)}
    if saved is not None:  # a decoder-only run stays one when resumed
        o.freeze_encoder = o.freeze_encoder or "encoder_from_sha256" in saved
    elif init is not None:
        if init["model_config"]["C_z"] != model.cfg.C_z:
            raise TrainError(f"--model-config: C_z {model.cfg.C_z} differs from "
                             f"{o.init_from}'s {init['model_config']['C_z']}")
        ckpt.load_state(model, init["state"], o.init_from)
        extra.update(warm_start_record(init, o.init_from))
        if o.freeze_encoder:  # the encoder whose latents a diffusion model may have been trained on
            extra["encoder_from_sha256"] = init.get("encoder_from_sha256", extra["init_from_sha256"])
        print(f"{o.init_from}: warm start from step {init['step']}")
    elif o.freeze_encoder:
        raise TrainError("--freeze-encoder needs --init-from (a trained encoder to keep)")
    if o.freeze_encoder:
        model.E.requires_grad_(False)
    opt = adam(torch.optim.Adam, [p for p in model.parameters() if p.requires_grad], lr=cfg.lr,
               weight_decay=cfg.weight_decay)
    # a token-reading decoder (C_t) sees the partial tokens the diffusion model is trained with
    mask_cfg = token_mask_config(cfg)

    def step_loss(module, batch, step):
        x, t, traj, told = batch["agents"], None, batch["traj"], None
        if model.cfg.C_t:
            x, t, traj, told = decoder_conditioning(batch, cfg.seed, step, rank(), mask_cfg, cfg.p_mislead,
                                                    model.token_raster, p_counterfactual=cfg.p_counterfactual)
        out = module.loss({"x": x, "m": batch["map"], "boxes": batch["boxes"],
                           "traj": traj, "traj_mask": batch["traj_mask"],
                           "valid": batch["valid"], "t": t, "told": told})
        return out["total"], {k: float(v.detach()) for k, v in out.items() if v.ndim == 0}

    Loop("autoencoder", o, cfg, model, opt, step_loss, extra=extra).run()


def train_diffusion(o) -> None:
    cfg = train_config(o, DIFFUSION_DEFAULTS)
    if not (0 <= cfg.p_keep_all_tokens and 0 <= cfg.p_map_only and cfg.p_keep_all_tokens + cfg.p_map_only <= 1):
        raise TrainError(f"--p-keep-all-tokens {cfg.p_keep_all_tokens:g} and --p-map-only {cfg.p_map_only:g}: "
                         f"need two probabilities summing to at most 1")
    ae_ck = load_training(o.autoencoder, "autoencoder-train")
    ae = ScenarioAutoencoder(ckpt.config_from_dict(AutoencoderConfig, ae_ck["model_config"]))
    ckpt.load_state(ae, ae_ck["state"], o.autoencoder)
    ae.eval().requires_grad_(False)
    last = os.path.join(o.out, "last.pt")
    saved = ckpt.load(last, "diffusion-train") if os.path.exists(last) else None
    init = load_training(o.init_from, "diffusion-train") if o.init_from and saved is None else None
    # a run continues with its own config, a warm start with its source's (--model-config on top);
    # the UNet denoises the autoencoder's latent: its c_z follows the autoencoder's C_z
    base = (saved or init or {}).get("model_config") or asdict(DiffusionConfig())
    base = _merge(base, {"unet": {"c_z": ae.cfg.C_z}})
    model = ScenarioDiffusion(model_config(o, DiffusionConfig, base=base, use_map=not o.no_map))
    if model.cfg.unet.c_z != ae.cfg.C_z:
        raise TrainError(f"--model-config: unet.c_z {model.cfg.unet.c_z} differs from "
                         f"{o.autoencoder}'s latent channels C_z {ae.cfg.C_z}")
    opt = adam(torch.optim.AdamW, model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    scale = {"value": None}
    mask_cfg = token_mask_config(cfg)

    def step_loss(module, batch, step):
        if scale["value"] is None:
            raise RuntimeError("latent scale not set")
        with torch.no_grad():
            z0 = ae.encode(batch["agents"])[0] * scale["value"]
        tokens, pad, glob, weight = conditioning(
            batch, seed=cfg.seed, step=step, device=z0.device, mask_cfg=mask_cfg,
            global_dim=model.cfg.unet.global_dim, token_loss_weight=cfg.token_loss_weight,
            res=model.cfg.unet.res)
        loss = module.loss(z0, batch["map"], tokens, pad, glob, weight=weight)
        return loss, {"edm": float(loss.detach())}

    extra = {"model_config": ckpt.config_to_dict(model.cfg),
             "autoencoder_sha256": ckpt.sha256(o.autoencoder)}
    if init is not None:
        ckpt.load_state(model, init.get("ema", init["state"]), o.init_from)
        extra.update(warm_start_record(init, o.init_from))
        if init.get("autoencoder_sha256") == extra["autoencoder_sha256"] and "latent_scale" in init:
            extra["latent_scale"] = init["latent_scale"]  # same latent space: same scale, on any data
        print(f"{o.init_from}: warm start from step {init['step']}")
    loop = Loop("diffusion", o, cfg, model, opt, step_loss, extra=extra, frozen=[ae])
    if cfg.compile:  # after the Loop's weight average copied the eager model
        compile_diffusion_stage(ae, model)
    scale["value"] = loop.extra.get("latent_scale") or estimate_latent_scale(ae, loop)
    loop.extra["latent_scale"] = scale["value"]
    loop.run()
