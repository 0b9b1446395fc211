"""Training settings of a stage (torch-free, so that the command line's --help and ``train recipe``
start without loading torch)."""
from __future__ import annotations

from dataclasses import dataclass

# the guidance weights `train calibrate` tries by default (1 = off)
CALIBRATION_WEIGHTS = (1.0, 1.5, 2.0, 2.5, 3.0)


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
    # diffusion, and an autoencoder whose decoder reads the tokens (C_t):
    # P(p_mask = 0), every agent a token (sec. 4.3.1 has 0.4) ...
    p_keep_all_tokens: float = 0.2
    # ... P(p_mask = 1), the map alone (the paper: 0; map-only generation drew half the agents
    # SUMO has when training never showed a window without tokens); else p_mask ~ Beta(2, 1)
    p_map_only: float = 0.3
    p_all_features: float = 0.5   # a kept token gives every feature (TokenMaskConfig)
    p_drop_group: float = 0.3     # ... else each feature group is dropped with this probability
    # diffusion: the denoising error of the latent cells under an agent kept as a positioned token
    # counts 1 + this many times (the rest of a scene dominates the mean otherwise)
    token_loss_weight: float = 0.0
    # an autoencoder whose decoder reads the tokens (C_t): the share of token features whose motion
    # the encoder is shown otherwise (train/token_decoder.py), so the decoder learns to follow the token
    p_mislead: float = 0.0
    p_counterfactual: float = 0.0   # ... of those, the share the other way round: the token and loss moved
    p_no_signals: float = 0.0     # scenes shown with their traffic lights unknown (a model without a host)
    seed: int = 0
    workers: int = 0              # DataLoader worker processes (rendering is ~2 % of a step)
    rotate: bool = True           # rotation augmentation of the training windows
    # diffusion stage: torch.compile the blocks where it pays on CPU (train/compiling.py, docs/training.md)
    compile: bool = True
