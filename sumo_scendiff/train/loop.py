"""The training loop shared by both stages: data, DDP, progress, validation, resumable checkpoints.

:class:`Loop` takes a model, an optimiser and ``step_loss(module, batch, step) -> (loss, logs)``;
it owns everything else. ``OUT/last.pt`` holds model, optimiser, scheduler, step, the best validation
loss, the data manifest and (when ``ema_halflife`` > 0) an exponential moving average of the weights:
starting again with the same output directory continues from there.
"""
from __future__ import annotations

import copy
import math
import os
import signal
import time
from dataclasses import asdict

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler, RandomSampler

from ..data.dataset import SceneDataset, collate_scenes
from ..data.shards import DataError, read_manifest
from ..model import checkpoint as ckpt
from ..tokens.encoding import (
    GLOBAL_TOKEN_DIM,
    features_from_scene,
    pad_tokens,
    token_cells,
)
from ..tokens.masking import TokenMaskConfig, partial_tokens

VAL_STEP = 1_000_000_000  # "step" given to step_loss in validation: its token masks never repeat training's


def distributed_setup() -> None:
    """Join the process group when started by torchrun (WORLD_SIZE > 1)."""
    if int(os.environ.get("WORLD_SIZE", "1")) > 1 and not dist.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend)
        if torch.cuda.is_available():
            torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))


def rank() -> int:
    return dist.get_rank() if dist.is_initialized() else 0


def world() -> int:
    return dist.get_world_size() if dist.is_initialized() else 1


def device() -> torch.device:
    if torch.cuda.is_available():
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    return torch.device("cpu")


class _LossModule(nn.Module):
    """Routes DDP's forward through ``step_loss`` so gradients are synchronised."""

    def __init__(self, model: nn.Module, step_loss):
        super().__init__()
        self.model, self.step_loss = model, step_loss

    def forward(self, batch, step):
        return self.step_loss(self.model, batch, step)


def token_loss_weights(tokens: torch.Tensor, pad: torch.Tensor, res: int, extra: float) -> torch.Tensor:
    """(B, 1, res, res): 1, and 1 + ``extra`` in the latent cells of the positioned tokens (the cells
    the UNet's token splat writes them into, ``tokens.encoding.token_cells``)."""
    cell, placed = token_cells(tokens, pad, res)
    w = torch.ones(tokens.shape[0], res * res, dtype=torch.float32, device=tokens.device)
    rows = torch.arange(tokens.shape[0], device=tokens.device)[:, None].expand_as(cell)
    w[rows[placed], cell[placed]] = 1.0 + extra
    return w.view(-1, 1, res, res)


def conditioning(batch: dict, seed: int, step: int, device,
                 mask_cfg: TokenMaskConfig = TokenMaskConfig(), global_dim: int = GLOBAL_TOKEN_DIM,
                 token_loss_weight: float = 0.0, res: int = 16) -> tuple:
    """Partial tokenisation of a batch (paper sec. 4.3.1): agent tokens, padding mask, global token
    (with the window's density for a model that takes it, ``global_dim``), and the loss weight of
    each latent cell ((B, 1, res, res): 1 + ``token_loss_weight`` under an agent kept as a
    positioned token; None when that weight is 0)."""
    toks, globs = [], []
    for i in range(batch["boxes"].shape[0]):
        v = batch["valid"][i].cpu().numpy()
        arrays = [batch[k][i].cpu().numpy()[v] for k in ("boxes", "traj", "traj_mask", "speed")]
        feats, present = features_from_scene(*arrays)
        rng = np.random.default_rng([seed, step, int(batch["index"][i]), rank()])
        density = float(batch["density"][i]) if "density" in batch else None
        tok, glob, _ = partial_tokens(feats, present, rng, mask_cfg, density=density, global_dim=global_dim)
        toks.append(tok)
        globs.append(glob)
    tokens, pad = pad_tokens(toks)
    tokens, pad = tokens.to(device), pad.to(device)
    weight = token_loss_weights(tokens, pad, res, token_loss_weight) if token_loss_weight > 0 else None
    return tokens, pad, torch.as_tensor(np.stack(globs), device=device), weight


def _to(batch: dict, dev) -> dict:
    return {k: (v.to(dev, non_blocking=True) if torch.is_tensor(v) else v) for k, v in batch.items()}


class EMA:
    """Exponential moving average of a model's weights (NVlabs/edm ``training_loop.py``): the half-life
    is ``halflife`` optimiser steps, but at most ``rampup`` times the steps taken so far, so that early
    weights fade quickly. ``beta = 0.5 ** (1 / halflife)`` per step."""

    def __init__(self, model: nn.Module, halflife: float, rampup: float):
        self.model = copy.deepcopy(model).eval().requires_grad_(False)
        self.halflife, self.rampup = halflife, rampup

    def beta(self, step: int) -> float:
        h = min(self.halflife, step * self.rampup) if self.rampup > 0 else self.halflife
        return 0.5 ** (1.0 / max(h, 1e-8))

    @torch.no_grad()
    def update(self, model: nn.Module, step: int) -> None:
        beta = self.beta(step)
        for p_ema, p in zip(self.model.parameters(), model.parameters()):
            p_ema.copy_(p.detach().lerp(p_ema, beta))
        for b_ema, b in zip(self.model.buffers(), model.buffers()):
            b_ema.copy_(b)


class TrainError(ValueError):
    """Bad input to a training stage (its flags, data or output directory): one line for the CLI."""


class Loop:
    def __init__(self, kind: str, o, cfg, model: nn.Module, opt, step_loss, extra=None, frozen=()):
        self.kind, self.o, self.cfg = kind, o, cfg
        self.dev = device()
        self.model = model.to(self.dev)
        for m in frozen:
            m.to(self.dev)
        self.opt = opt
        self.sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.1,
                                                                patience=cfg.plateau_patience)
        self.ema = EMA(self.model, cfg.ema_halflife, cfg.ema_rampup) if cfg.ema_halflife > 0 else None
        self.step_loss = step_loss
        self.extra = dict(extra or {})
        self.step, self.best_val = 0, math.inf
        self.path = os.path.join(o.out, "last.pt")
        try:
            manifests = [read_manifest(d) for d in o.data]
            self.data_manifest = {"scenes": sum(m["scenes"] for m in manifests),
                                  "nets": [n["name"] for m in manifests for n in m["nets"]]}
            self.train_set = SceneDataset(o.data, rotate=cfg.rotate, seed=cfg.seed, p_no_signals=cfg.p_no_signals)
            self.val_set = SceneDataset(o.val, rotate=True, seed=12345) if o.val else None
        except DataError as e:
            raise TrainError(str(e)) from None
        if os.path.exists(self.path):
            self._resume()
        elif os.path.isdir(o.out) and os.listdir(o.out):
            raise TrainError(f"{o.out}: not empty and holds no last.pt (choose another --output-dir)")
        self.ddp = _LossModule(self.model, step_loss)
        if world() > 1:
            self.ddp = nn.parallel.DistributedDataParallel(self.ddp)

    # ---- checkpoints ----------------------------------------------------------------------
    def _resume(self) -> None:
        ck = ckpt.load(self.path, f"{self.kind}-train")
        ckpt.load_state(self.model, ck["state"], self.path)
        self.opt.load_state_dict(ck["optimizer"])
        self.sched.load_state_dict(ck["scheduler"])
        self.step, self.best_val = ck["step"], ck.get("best_val", math.inf)
        if getattr(self.o, "lr", None) is not None:  # an explicit --lr wins over the saved one
            self._set_lr(self.cfg.lr)
        if self.cfg.lr_drop_at and self.step >= self.cfg.lr_drop_at:
            self._set_lr(min(self.opt.param_groups[0]["lr"], 0.1 * self.cfg.lr))
        if self.ema is not None and "ema" in ck:  # (a run saved without an average starts one here)
            ckpt.load_state(self.ema.model, ck["ema"], self.path)
        self.extra.update({k: ck[k] for k in ("latent_scale", "init_from_sha256", "encoder_from_sha256",
                                                "steps_before") if k in ck})
        if rank() == 0:
            print(f"{self.path}: resuming at step {self.step}")

    def _set_lr(self, lr: float) -> None:
        for group in self.opt.param_groups:
            group["lr"] = lr

    def save(self) -> None:
        if rank() != 0:
            return
        if self.ema is not None:
            self.extra["ema"] = self.ema.model.state_dict()
        ckpt.save(self.path, f"{self.kind}-train", state=self.model.state_dict(),
                  optimizer=self.opt.state_dict(), scheduler=self.sched.state_dict(), step=self.step,
                  best_val=self.best_val, train_config=asdict(self.cfg),
                  world_size=world(),  # processes: the global batch is batch_size x world_size
                  data_manifest=self.data_manifest,
                  **self.extra)

    # ---- data -----------------------------------------------------------------------------
    def loader(self, ds, epoch: int, shuffle: bool = True) -> DataLoader:
        ds.set_epoch(epoch)
        if world() > 1:
            sampler = DistributedSampler(ds, world(), rank(), shuffle=shuffle, seed=self.cfg.seed)
            sampler.set_epoch(epoch)
        else:
            g = torch.Generator().manual_seed(self.cfg.seed * 1000 + epoch)
            sampler = RandomSampler(ds, generator=g) if shuffle else None
        return DataLoader(ds, batch_size=self.cfg.batch_size, sampler=sampler, drop_last=shuffle,
                          collate_fn=collate_scenes, num_workers=self.cfg.workers,
                          persistent_workers=False)

    def batches(self):
        """Endless stream of training batches, continuing the epoch count on resume."""
        per_epoch = max(1, len(self.train_set) // (self.cfg.batch_size * world()))
        epoch, skip = divmod(self.step, per_epoch)
        while True:
            for k, batch in enumerate(self.loader(self.train_set, epoch)):
                if k >= skip:
                    yield _to(batch, self.dev)
            epoch, skip = epoch + 1, 0

    # ---- validation -----------------------------------------------------------------------
    @torch.no_grad()
    def validate(self, model: nn.Module | None = None) -> float:
        """Mean validation loss of ``model`` (default: the trained weights) on fixed noise."""
        if self.val_set is None:
            return math.nan
        model = model or self.model
        was_training = model.training
        model.eval()
        losses = []
        torch_state = torch.get_rng_state()
        torch.manual_seed(12345)  # the same noise every validation: comparable numbers
        for k, batch in enumerate(self.loader(self.val_set, 0, shuffle=False)):
            if k >= self.cfg.val_batches:
                break
            loss, _ = self.step_loss(model, _to(batch, self.dev), VAL_STEP + k)
            losses.append(float(loss))
        torch.set_rng_state(torch_state)
        model.train(was_training)
        val = float(np.mean(losses))
        if world() > 1:
            t = torch.tensor([val], device=self.dev)
            dist.all_reduce(t)
            val = float(t) / world()
        return val

    # ---- the loop -------------------------------------------------------------------------
    def run(self) -> None:
        from tqdm import tqdm
        cfg, o = self.cfg, self.o
        torch.manual_seed(cfg.seed + self.step + 7919 * rank())
        deadline = time.time() + 60 * o.max_minutes if o.max_minutes else math.inf
        bar = tqdm(total=cfg.steps, initial=self.step, desc=self.kind, disable=rank() != 0,
                   dynamic_ncols=True)
        self.model.train()
        stream = self.batches()
        stop = {"signal": None}

        def on_signal(signum, frame):  # finish the step, save, exit: no progress lost
            stop["signal"] = signum

        old_handlers = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            while self.step < cfg.steps and time.time() < deadline and stop["signal"] is None:
                batch = next(stream)
                loss, logs = self.ddp(batch, self.step)
                self.opt.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.model.parameters(), cfg.grad_clip)
                self.opt.step()
                self.step += 1
                if self.ema is not None:
                    self.ema.update(self.model, self.step)
                if self.step == cfg.lr_drop_at:  # a fixed step schedule instead of the plateau rule
                    self._set_lr(0.1 * cfg.lr)
                bar.update(1)
                bar.set_postfix({k: f"{v:.3g}" for k, v in list(logs.items())[:4]})
                if self.step % cfg.val_every == 0 or self.step == cfg.steps:
                    val = self.validate()
                    if not math.isnan(val):
                        if not cfg.lr_drop_at:
                            self.sched.step(val)
                        self.best_val = min(self.best_val, val)
                    ema = f", ema {self.validate(self.ema.model):.4f}" if self.ema and self.val_set else ""
                    if rank() == 0:
                        bar.write(f"step {self.step}: val {val:.4f} (best {self.best_val:.4f}){ema} "
                                  f"lr {self.opt.param_groups[0]['lr']:.1e}")
                if self.step % cfg.ckpt_every == 0:
                    self.save()
        finally:
            self.save()
            bar.close()
            for s, h in old_handlers.items():
                signal.signal(s, h)
        if stop["signal"] is not None:
            if rank() == 0:
                print(f"stopped by signal {stop['signal']} at step {self.step}: saved {self.path}")
            # not finished: a shell's status for a signal, so that whoever runs the stage (the
            # recipe, a job queue) starts it again instead of taking it as done
            raise SystemExit(128 + stop["signal"])


@torch.no_grad()
def estimate_latent_scale(ae: nn.Module, loop: Loop, batches: int = 16) -> float:
    """sigma_data / std(mu) over training batches (latent diffusion's scale factor; EDM wants
    latents with standard deviation sigma_data = 0.5)."""
    mus = []
    for k, batch in enumerate(loop.loader(loop.train_set, 10_000)):
        if k >= batches:
            break
        mus.append(ae.encode(batch["agents"].to(loop.dev))[0].flatten())
    std = float(torch.cat(mus).std())
    if rank() == 0:
        print(f"latent std {std:.4f}: scale {0.5 / std:.4f}")
    return 0.5 / max(std, 1e-6)


def load_training(path: str, kind: str) -> dict:
    """A training checkpoint of ``kind`` ("autoencoder-train" or "diffusion-train"), or that half of an
    exported model (the shipped weights) in the same form: fine-tune the shipped model without its runs."""
    ck = ckpt.load(path, (kind, "scenario-diffusion"))
    if ck["kind"] == kind:
        return ck
    part, trained = kind.split("-")[0], ck.get("trained", {})
    view = {"kind": kind, "model_config": ck[part + "_config"], "step": trained.get(part + "_steps", 0),
            "state": {k: v.float() if v.is_floating_point() else v for k, v in ck[part].items()},
            "best_val": trained.get(part + "_val"), "data_manifest": trained.get("data")}
    if part == "diffusion":  # exported weights are the weight average; the latent space is this file's
        view.update(ema=view["state"], latent_scale=ck["latent_scale"], autoencoder_sha256=ckpt.sha256(path))
    return view
