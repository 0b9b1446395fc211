"""Train Scenario Diffusion: the detection autoencoder, then the latent diffusion model, then export.

    python -m sumo_scendiff.train autoencoder --data data/train --val data/val -o runs/ae --steps 6000
    python -m sumo_scendiff.train diffusion --autoencoder runs/ae/last.pt --data data/train \\
        --val data/val -o runs/diffusion --steps 8000
    python -m sumo_scendiff.train autoencoder --init-from runs/ae/last.pt --freeze-encoder ...  # decoder only
    python -m sumo_scendiff.train diffusion --autoencoder sumo_scendiff/weights/scendiff.pt \\
        --init-from sumo_scendiff/weights/scendiff.pt ...  # fine-tune the shipped model
    python -m sumo_scendiff.train export --autoencoder runs/ae/last.pt \\
        --diffusion runs/diffusion/last.pt -o sumo_scendiff/weights/scendiff.pt

Each stage writes ``OUT/last.pt`` every ``--ckpt-every`` steps (and when ``--max-minutes`` runs out or
on Ctrl-C) and continues from it when started again with the same ``-o``: a stopped run loses at most
the steps since its last checkpoint. Uses CUDA when present; runs unchanged under
``torchrun --nproc_per_node N python -m sumo_scendiff.train ...`` (DistributedDataParallel; gloo on CPU).
The shipped model's recipe is ``scripts/train_fast.sh`` (every stage as two one-thread DDP processes).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import asdict, dataclass

# OpenMP threads that spin while waiting make torch ~4x slower whenever anything else runs on a
# 2-core machine (measured here); must be set before torch starts its thread pool.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from ..model import checkpoint as ckpt  # noqa: E402
from ..model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from ..model.blocks import widen_input, widen_output
from ..model.diffusion import DiffusionConfig, ScenarioDiffusion
from ..model.unet import grow_latent, widen_conv_in
from ..tokens.masking import TokenMaskConfig
from .loop import (
    Loop,
    conditioning,
    distributed_setup,
    estimate_latent_scale,
    load_training,
)

PROG = "python -m sumo_scendiff.train"


@dataclass
class TrainConfig:
    steps: int = 6000
    batch_size: int = 16
    lr: float = 3e-4
    weight_decay: float = 1e-4
    grad_clip: float = 1.0        # appendix C.3
    val_every: int = 500
    val_batches: int = 8
    ckpt_every: int = 250
    plateau_patience: int = 3     # validations without improvement before lr /= 10
    lr_drop_at: int = 0           # step at which lr /= 10 (a fixed schedule); 0: the plateau rule
    ema_halflife: float = 0.0     # weight average half-life in steps (0: none); export uses it
    ema_rampup: float = 0.05      # ... but at most this fraction of the steps so far (EDM's rule)
    p_keep_all_tokens: float = 0.4  # diffusion: P(p_mask = 0), every agent a token (sec. 4.3.1)
    p_map_only: float = 0.0       # diffusion: P(p_mask = 1), the map alone; else p_mask ~ Beta(2, 1)
    seed: int = 0
    workers: int = 0              # DataLoader worker processes (rendering is ~2 % of a step)
    rotate: bool = True           # rotation augmentation of the training windows


def get_options(args=None):
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="stage", required=True)
    for name in ("autoencoder", "diffusion"):
        s = sub.add_parser(name)
        s.add_argument("--data", required=True, nargs="+",
                       help="training data directory (sumo_scendiff.data); several are read as one")
        s.add_argument("--val", default=None, nargs="+", help="validation data directory (or several)")
        s.add_argument("-o", "--output-dir", dest="out", required=True)
        s.add_argument("--max-minutes", type=float, default=None, help="stop (and save) after this")
        s.add_argument("-v", "--verbose", action="store_true")
        for f, default in asdict(TrainConfig()).items():
            if isinstance(default, bool):
                s.add_argument("--" + f.replace("_", "-"), action=argparse.BooleanOptionalAction,
                               default=None)
            else:
                s.add_argument("--" + f.replace("_", "-"), type=type(default), default=None)
        s.add_argument("--model-config", type=json.loads, default={}, metavar="JSON",
                       help='override model config fields, e.g. \'{"enc_channels": [8, 16, 32, 32]}\'')
        s.add_argument("--init-from", default=None, metavar="CKPT",
                       help=f"warm start a new run from the weights of an earlier {name} run (its "
                            "last.pt; for diffusion its weight average, new input channels at zero) or of "
                            "an exported model (the shipped one); "
                            "ignored when resuming")
        if name == "autoencoder":
            s.add_argument("--freeze-encoder", action="store_true",
                           help="train the decoder only (needs --init-from): the latent space stays "
                                "the same, so a diffusion model trained on it stays valid")
        if name == "diffusion":
            s.add_argument("--autoencoder", required=True, help="autoencoder checkpoint (last.pt, or an exported "
                           "model such as the shipped one)")
        s.add_argument("--no-map", action="store_true",
                       help=f"the paper's no-map ablation: the {name} model sees the map as zeros")
    e = sub.add_parser("export")
    e.add_argument("--autoencoder", required=True)
    e.add_argument("--diffusion", required=True)
    e.add_argument("-o", "--output", required=True)
    e.add_argument("--fp16", action="store_true", help="store weights in float16 (half the size)")
    e.add_argument("--force", action="store_true", help="replace an existing output file")
    e.add_argument("--scene-guidance", type=float, default=1.0, metavar="W",
                   help="the global token's guidance weight generation uses by default (1 = off; "
                        "calibrate with benchmarks/scene_guidance.py)")
    e.add_argument("--scene-guidance-sigma", type=float, default=0.0, metavar="SIGMA",
                   help="apply that guidance only at noise levels above SIGMA (0 = at every step)")
    o = p.parse_args(args)
    o.parser = p
    return o


def train_config(o, defaults: TrainConfig) -> TrainConfig:
    kw = {f: getattr(o, f) for f in asdict(defaults) if getattr(o, f, None) is not None}
    return TrainConfig(**{**asdict(defaults), **kw})


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
        o.parser.exit(2, f"{PROG}: error: --model-config: {e}\n")


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
    extra = {"model_config": ckpt.config_to_dict(model.cfg)}
    if saved is not None:  # a decoder-only run stays one when resumed
        o.freeze_encoder = o.freeze_encoder or "encoder_from_sha256" in saved
    elif init is not None:
        state = init["state"]
        if all(k.startswith("D_up.skips.") for k in set(model.state_dict()) - set(state)):
            state = {**model.state_dict(), **state}  # map skips the source lacks start at zero
        # map channels the source lacks (a larger C_m) start at zero
        state = widen_input(state, "D_down.conv_in.weight", model.D_down.conv_in.weight)
        for key in ("D_up.conv_out.weight", "D_up.conv_out.bias"):  # a heading head the source lacks
            state = widen_output(state, key, model.state_dict()[key])
        old_c_z = init["model_config"]["C_z"]
        if old_c_z != model.cfg.C_z and o.freeze_encoder:
            o.parser.exit(2, f"{PROG}: error: --freeze-encoder keeps the latent space: C_z {model.cfg.C_z} "
                             f"differs from {o.init_from}'s {old_c_z}\n")
        try:  # a larger latent (C_z): the new channels start unused by the decoder
            state = model.grow_latent(state, old_c_z)
        except ValueError as e:
            o.parser.exit(2, f"{PROG}: error: {o.init_from}: {e}\n")
        ckpt.load_state(model, state, o.init_from)
        extra.update(warm_start_record(init, o.init_from))
        if o.freeze_encoder:  # the encoder whose latents a diffusion model may have been trained on
            extra["encoder_from_sha256"] = init.get("encoder_from_sha256", extra["init_from_sha256"])
        print(f"{o.init_from}: warm start from step {init['step']}")
    elif o.freeze_encoder:
        o.parser.exit(2, f"{PROG}: error: --freeze-encoder needs --init-from (a trained encoder to keep)\n")
    if o.freeze_encoder:
        model.E.requires_grad_(False)
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=cfg.lr,
                           weight_decay=cfg.weight_decay)

    def step_loss(module, batch, step):
        out = module.loss({"x": batch["agents"], "m": batch["map"], "boxes": batch["boxes"],
                           "traj": batch["traj"], "traj_mask": batch["traj_mask"],
                           "valid": batch["valid"]})
        return out["total"], {k: float(v.detach()) for k, v in out.items() if v.ndim == 0}

    Loop("autoencoder", o, cfg, model, opt, step_loss, extra=extra).run()


def train_diffusion(o) -> None:
    cfg = train_config(o, TrainConfig(steps=8000, lr=3e-4, weight_decay=1e-5, ema_halflife=250.0))
    if not (0 <= cfg.p_keep_all_tokens and 0 <= cfg.p_map_only and cfg.p_keep_all_tokens + cfg.p_map_only <= 1):
        o.parser.exit(2, f"{PROG}: error: --p-keep-all-tokens {cfg.p_keep_all_tokens:g} and --p-map-only "
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
        o.parser.exit(2, f"{PROG}: error: --model-config: unet.c_z {model.cfg.unet.c_z} differs from "
                         f"{o.autoencoder}'s latent channels C_z {ae.cfg.C_z}\n")
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    scale = {"value": None}
    mask_cfg = TokenMaskConfig(p_keep_all_tokens=cfg.p_keep_all_tokens, p_map_only=cfg.p_map_only)

    def step_loss(module, batch, step):
        if scale["value"] is None:
            raise RuntimeError("latent scale not set")
        with torch.no_grad():
            z0 = ae.encode(batch["agents"])[0] * scale["value"]
        tokens, pad, glob = conditioning(batch, seed=cfg.seed, step=step, device=z0.device,
                                         mask_cfg=mask_cfg)
        loss = module.loss(z0, batch["map"], tokens, pad, glob)
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
            o.parser.exit(2, f"{PROG}: error: {o.init_from}: {e}\n")
        state = widen_conv_in(state, model.denoiser.net, prefix="denoiser.net.")
        state = widen_input(state, "E_m.conv_in.weight", model.E_m.conv_in.weight)  # map channels added
        ckpt.load_state(model, state, o.init_from)
        extra.update(warm_start_record(init, o.init_from))
        if init.get("autoencoder_sha256") == extra["autoencoder_sha256"] and "latent_scale" in init:
            extra["latent_scale"] = init["latent_scale"]  # same latent space: same scale, on any data
        print(f"{o.init_from}: warm start from step {init['step']}")
    loop = Loop("diffusion", o, cfg, model, opt, step_loss, extra=extra, frozen=[ae])
    scale["value"] = loop.extra.get("latent_scale") or estimate_latent_scale(ae, loop)
    loop.extra["latent_scale"] = scale["value"]
    loop.run()


def export(o) -> None:
    if not o.scene_guidance >= 0:
        o.parser.exit(2, f"{PROG}: error: --scene-guidance must be >= 0\n")
    if not o.scene_guidance_sigma >= 0:
        o.parser.exit(2, f"{PROG}: error: --scene-guidance-sigma must be >= 0\n")
    if os.path.exists(o.output) and not o.force:
        o.parser.exit(2, f"{PROG}: error: {o.output}: exists (add --force to replace it)\n")
    ae_ck = load_training(o.autoencoder, "autoencoder-train")
    df_ck = load_training(o.diffusion, "diffusion-train")
    # a decoder-only fine-tune (--freeze-encoder) keeps the latent space the diffusion was trained in
    if df_ck["autoencoder_sha256"] not in (ckpt.sha256(o.autoencoder), ae_ck.get("encoder_from_sha256")):
        o.parser.exit(2, f"{PROG}: error: {o.diffusion}: was trained on another autoencoder than "
                         f"{o.autoencoder}\n")

    def cast(state):
        return {k: (v.half() if o.fp16 and v.is_floating_point() else v) for k, v in state.items()}

    sha = ckpt.save(o.output, "scenario-diffusion",
                    autoencoder_config=ae_ck["model_config"], autoencoder=cast(ae_ck["state"]),
                    diffusion_config=df_ck["model_config"],
                    diffusion=cast(df_ck.get("ema", df_ck["state"])),  # the weight average when kept
                    latent_scale=float(df_ck["latent_scale"]),
                    scene_guidance=float(o.scene_guidance),
                    scene_guidance_sigma=float(o.scene_guidance_sigma),
                    # steps over every warm start (a run's own steps plus those it started from)
                    trained={"autoencoder_steps": ae_ck["step"] + ae_ck.get("steps_before", 0),
                             "diffusion_steps": df_ck["step"] + df_ck.get("steps_before", 0),
                             "diffusion_ema": "ema" in df_ck,
                             "autoencoder_val": ae_ck.get("best_val"),
                             "diffusion_val": df_ck.get("best_val"),
                             "data": df_ck.get("data_manifest")})
    print(f"{o.output}: {os.path.getsize(o.output) / 2**20:.1f} MiB, sha256 {sha}")


def main(o) -> int:
    torch.manual_seed(0)
    np.random.seed(0)
    try:
        if o.stage == "export":
            export(o)
            return 0
        distributed_setup()
        (train_autoencoder if o.stage == "autoencoder" else train_diffusion)(o)
    except ckpt.CheckpointError as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
