"""The two training stages: the detection autoencoder and the latent diffusion model in its latent space.

Each takes the parsed options of its ``train`` subcommand (``o.parser`` reports bad input, exit 2, as
the training loop does) and runs :class:`~sumo_scendiff.train.loop.Loop` until ``--steps``.
"""
from __future__ import annotations

import os
from dataclasses import asdict

import torch

from ..model import checkpoint as ckpt
from ..model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from ..model.blocks import widen_input, widen_output
from ..model.diffusion import DiffusionConfig, ScenarioDiffusion
from ..model.unet import grow_latent, widen_conv_in
from ..tokens.masking import TokenMaskConfig
from ..tokens.raster import C_T
from .config import TrainConfig
from .loop import Loop, conditioning, estimate_latent_scale, load_training, rank
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
        o.parser.exit(2, f"{o.parser.prog}: error: --model-config: {e}\n")


def warm_start_record(init: dict, path: str) -> dict:
    """What a warm-started run keeps of its source: its SHA-256 and the steps behind it."""
    return {"init_from_sha256": ckpt.sha256(path), "steps_before": init["step"] + init.get("steps_before", 0)}


def train_autoencoder(o) -> None:
    cfg = train_config(o, TrainConfig(steps=6000, lr=3e-4, weight_decay=1e-4))
    last = os.path.join(o.out, "last.pt")
    saved = ckpt.load(last, "autoencoder-train") if os.path.exists(last) else None
    init = load_training(o.init_from, "autoencoder-train") if o.init_from and saved is None else None
    # a run continues with its own config, a warm start with its source's (--model-config on top)
    base = (saved or init or {}).get("model_config")
    model = ScenarioAutoencoder(model_config(o, AutoencoderConfig, base=base,
                                             **({"use_map": False} if o.no_map else {})))
    if model.cfg.C_t not in (0, C_T):
        o.parser.exit(2, f"{o.parser.prog}: error: --model-config: C_t {model.cfg.C_t}: the token raster has "
                         f"{C_T} channels (0: a decoder without tokens)\n")
    extra = {"model_config": ckpt.config_to_dict(model.cfg)}
    if saved is not None:  # a decoder-only run stays one when resumed
        o.freeze_encoder = o.freeze_encoder or "encoder_from_sha256" in saved
    elif init is not None:
        state = init["state"]
        if all(k.startswith(("D_up.skips.", "D_up.tokens.", "D_up.branch.")) for k in set(model.state_dict()) - set(state)):
            # map skips, token inputs or a token branch the source lacks start as new (adding nothing)
            state = {**model.state_dict(), **state}
        # map channels the source lacks (a larger C_m) start at zero
        state = widen_input(state, "D_down.conv_in.weight", model.D_down.conv_in.weight)
        for key in ("D_up.conv_out.weight", "D_up.conv_out.bias"):  # a heading head the source lacks
            state = widen_output(state, key, model.state_dict()[key])
        old_c_z = init["model_config"]["C_z"]
        if old_c_z != model.cfg.C_z and o.freeze_encoder:
            o.parser.exit(2, f"{o.parser.prog}: error: --freeze-encoder keeps the latent space: C_z {model.cfg.C_z} "
                             f"differs from {o.init_from}'s {old_c_z}\n")
        try:  # a larger latent (C_z): the new channels start unused by the decoder
            state = model.grow_latent(state, old_c_z)
        except ValueError as e:
            o.parser.exit(2, f"{o.parser.prog}: error: {o.init_from}: {e}\n")
        ckpt.load_state(model, state, o.init_from)
        extra.update(warm_start_record(init, o.init_from))
        if o.freeze_encoder:  # the encoder whose latents a diffusion model may have been trained on
            extra["encoder_from_sha256"] = init.get("encoder_from_sha256", extra["init_from_sha256"])
        print(f"{o.init_from}: warm start from step {init['step']}")
    elif o.freeze_encoder:
        o.parser.exit(2, f"{o.parser.prog}: error: --freeze-encoder needs --init-from (a trained encoder to keep)\n")
    if o.freeze_encoder:
        model.E.requires_grad_(False)
    if cfg.token_weights_only:
        if not model.cfg.C_t:
            o.parser.exit(2, f"{o.parser.prog}: error: --token-weights-only: the decoder reads no tokens (C_t 0)\n")
        for k, p in model.named_parameters():
            p.requires_grad_(k.startswith("D_up.tokens.") and k.endswith(".weight"))
    if cfg.token_branch_only:
        if model.D_up.branch is None:
            o.parser.exit(2, f"{o.parser.prog}: error: --token-branch-only: the decoder has no token branch "
                             f"(--model-config token_branch 0)\n")
        for k, p in model.named_parameters():
            p.requires_grad_(k.startswith("D_up.branch."))
    # the token inputs of a token-reading decoder learning faster: a group of their own, after the
    # first (whose rate the loop reports); one group otherwise, as runs saved before resume
    fast = cfg.token_lr_scale != 1.0
    own = [p for k, p in model.named_parameters() if p.requires_grad and not (fast and k.startswith("D_up.tokens."))]
    new = [p for k, p in model.named_parameters() if fast and k.startswith("D_up.tokens.")]
    groups = [{"params": own}] + ([{"params": new, "lr": cfg.lr * cfg.token_lr_scale,
                                    "lr_scale": cfg.token_lr_scale}] if new else [])
    opt = torch.optim.Adam(groups, lr=cfg.lr, weight_decay=cfg.weight_decay)
    # a token-reading decoder (C_t) sees the partial tokens the diffusion model is trained with
    mask_cfg = token_mask_config(cfg)

    def step_loss(module, batch, step):
        x, t, traj, told = batch["agents"], None, batch["traj"], None
        if model.cfg.C_t:
            x, t, traj, told = decoder_conditioning(batch, cfg.seed, step, rank(), mask_cfg, cfg.p_mislead,
                                              model.token_raster, p_counterfactual=cfg.p_counterfactual,
                                              exact=cfg.exact_token_values)
        out = module.loss({"x": x, "m": batch["map"], "boxes": batch["boxes"],
                           "traj": traj, "traj_mask": batch["traj_mask"],
                           "valid": batch["valid"], "t": t, "told": told})
        return out["total"], {k: float(v.detach()) for k, v in out.items() if v.ndim == 0}

    Loop("autoencoder", o, cfg, model, opt, step_loss, extra=extra).run()


def train_diffusion(o) -> None:
    cfg = train_config(o, TrainConfig(steps=8000, lr=3e-4, weight_decay=1e-5, ema_halflife=250.0))
    if not (0 <= cfg.p_keep_all_tokens and 0 <= cfg.p_map_only and cfg.p_keep_all_tokens + cfg.p_map_only <= 1):
        o.parser.exit(2, f"{o.parser.prog}: error: --p-keep-all-tokens {cfg.p_keep_all_tokens:g} and --p-map-only "
                         f"{cfg.p_map_only:g}: need two probabilities summing to at most 1\n")
    ae_ck = load_training(o.autoencoder, "autoencoder-train")
    ae = ScenarioAutoencoder(ckpt.config_from_dict(AutoencoderConfig, ae_ck["model_config"]))
    ckpt.load_state(ae, ae_ck["state"], o.autoencoder)
    ae.eval().requires_grad_(False)
    last = os.path.join(o.out, "last.pt")
    saved = ckpt.load(last, "diffusion-train") if os.path.exists(last) else None
    # a run continues with its own config (--model-config on top), a warm start with the defaults'
    # the UNet denoises the autoencoder's latent: its c_z follows the autoencoder's C_z
    base = (saved or {}).get("model_config") or asdict(DiffusionConfig())
    base = _merge(base, {"unet": {"c_z": ae.cfg.C_z}})
    model = ScenarioDiffusion(model_config(o, DiffusionConfig, base=base, use_map=not o.no_map))
    if model.cfg.unet.c_z != ae.cfg.C_z:
        o.parser.exit(2, f"{o.parser.prog}: error: --model-config: unet.c_z {model.cfg.unet.c_z} differs from "
                         f"{o.autoencoder}'s latent channels C_z {ae.cfg.C_z}\n")
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
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
    if o.init_from and saved is None:
        init = load_training(o.init_from, "diffusion-train")
        state = init.get("ema", init["state"])
        try:  # an autoencoder with a larger latent: the new channels start at zero weights
            state = grow_latent(state, model.denoiser.net, init["model_config"]["unet"]["c_z"],
                                prefix="denoiser.net.")
        except ValueError as e:
            o.parser.exit(2, f"{o.parser.prog}: error: {o.init_from}: {e}\n")
        state = widen_conv_in(state, model.denoiser.net, prefix="denoiser.net.")
        state = widen_input(state, "E_m.conv_in.weight", model.E_m.conv_in.weight)  # map channels added
        own = model.state_dict()
        for key in ("denoiser.net.global_emb.weight", "denoiser.net.global_mlp.0.weight"):
            if key in own:   # the density condition added to a model without it: zero weights
                state = widen_input(state, key, own[key])
        ckpt.load_state(model, state, o.init_from)
        extra.update(warm_start_record(init, o.init_from))
        if init.get("autoencoder_sha256") == extra["autoencoder_sha256"] and "latent_scale" in init:
            extra["latent_scale"] = init["latent_scale"]  # same latent space: same scale, on any data
        print(f"{o.init_from}: warm start from step {init['step']}")
    loop = Loop("diffusion", o, cfg, model, opt, step_loss, extra=extra, frozen=[ae])
    scale["value"] = loop.extra.get("latent_scale") or estimate_latent_scale(ae, loop)
    loop.extra["latent_scale"] = scale["value"]
    loop.run()
