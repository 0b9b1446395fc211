"""Generation settings: the one place that defines them."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..model.edm import sample_dpmpp_2m


@dataclass
class GenerationConfig:
    # DPM-Solver++(2M) at 10 steps: the quality of 20 Euler steps (the paper's solver) at half the
    # UNet passes (README, "The model"); any solver of model.edm fits (sampler=sample_euler)
    steps: int = 10
    sampler: Callable = sample_dpmpp_2m
    threshold: float = 0.8       # box probability (paper sec. 4.1: 80 %)
    batch_size: int = 32
    guidance: float = 3.0        # classifier-free guidance weight of the agent tokens (1 = off);
                                 # costs a second UNet pass only for batches that carry tokens
    scene_guidance: float | None = None  # ... of the global token, for windows without agent tokens
                                         # (1 = off; None: the checkpoint's calibrated weight)
    scene_guidance_sigma: float | None = None  # ... applied only at noise levels above this
                                               # (None: the checkpoint's, calibrated with the weight)
    pin_tokens: bool = True      # a token giving pose, size and speed is imposed in the latent
                                 # (pinning.py) and its agent takes the token's heading; False:
                                 # every token is a condition only (the paper)
    pin_calibration: bool = True   # ... drawn at the speeds the decoder turns into the token's
                                   # (pinning.calibrated_pins; README "The model", pinned tokens)
    pin_speeds: bool = True      # ... and its agent moves along its decoded path at the token's
                                 # speed and final speed, and turns by its heading_to_final
                                 # (pinning.pace_to_pins); False: the decoder's speeds and path
                                 # (what the paper's Table 3 measures)
    lane_headings: bool = True   # a box on a junction takes the heading of the network's lane through
                                 # it that the heading head finds most probable (lane_heading.py)
    lane_snap: bool = True       # poses within 3 m of an agreeing car lane move onto its centre line
                                 # and take its heading, as SUMO's traffic drives (lane_snap.py);
                                 # an agent on no such lane is removed unless a token put it there
