"""torch.compile (inductor) of the blocks of a training step where it pays on CPU (docs/training.md,
"torch.compile"): in the diffusion stage, the autoencoder's frozen encoder E, which only ever runs
without gradients, and the map encoder E_m while it trains. The autoencoder stages gain nothing
from it (their convolutions' backward is the step), so they train eagerly.

The blocks are compiled in place by replacing their instance's ``forward``: the module tree, its
``state_dict`` keys (no ``_orig_mod.``) and its checkpoints stay the eager model's. A trained
block runs eagerly without gradients (validation), where its compiled training graph does not
apply and a second compile would cost more than the few batches it serves.
"""
from __future__ import annotations

import torch
from torch import nn

from .loop import TrainError


def _failed(name: str, err: Exception) -> TrainError:
    first = (str(err).strip().splitlines() or [type(err).__name__])[0]
    return TrainError(f"torch.compile of {name} failed ({first}); train with --no-compile")


def _guarded(name: str, fn):
    """``fn`` with a failure of the compiler (no C++ compiler, an unsupported operator) as one line."""
    from torch._dynamo.exc import TorchDynamoException

    def call(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except TorchDynamoException as e:
            raise _failed(name, e) from None
    return call


def compile_frozen(module: nn.Module, name: str) -> None:
    """``module`` (no weight learning; its input a recording's raster) compiled for inference: its
    forward runs without gradients, which it never needs, so one graph serves training and
    validation alike."""
    compiled = _guarded(name, torch.compile(module.forward, dynamic=False))

    def forward(*args, **kwargs):
        with torch.no_grad():
            return compiled(*args, **kwargs)
    module.forward = forward


def compile_trained(module: nn.Module, name: str) -> None:
    """``module`` compiled while gradients are on (its training steps), eager without them."""
    eager, compiled = module.forward, _guarded(name, torch.compile(module.forward, dynamic=False))

    def forward(*args, **kwargs):
        return (compiled if torch.is_grad_enabled() else eager)(*args, **kwargs)
    module.forward = forward


def compile_diffusion_stage(ae: nn.Module, model: nn.Module) -> None:
    """The diffusion stage's blocks that pay compiled: the frozen E (inference), E_m (training).
    The UNet is left eager: its token count changes from batch to batch, each a compile of its own."""
    compile_frozen(ae.E, "the autoencoder's encoder E")
    compile_trained(model.E_m, "the map encoder E_m")
