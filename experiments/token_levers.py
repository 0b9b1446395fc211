"""Inference-time levers on the model's own following of partial tokens (no retraining).

    python experiments/token_levers.py [--null map|kinematics] [--token-sigma-lo S] -- [user_tokens.py options]

Runs ``user_tokens.py`` (drawn column: ``--drawn-only``) with the token guidance changed where the
generator does not expose it (``ScenarioDiffusion.null_condition``, patched here only):

* ``--null map`` (the generator's): a window with agent tokens is guided away from the map alone
  (no token, p_mask 1): the weight amplifies *that there are* the token's agents (and fewer others)
  together with what they say;
* ``--null kinematics``: away from the same tokens without their ``speed``, ``final_speed`` and
  ``heading_to_final`` (position, heading and size kept, the same global token): the weight
  amplifies only what those features add;
* ``--token-sigma-lo S``: the token guidance only while sigma > S (a guidance interval, as the
  global token's; default 0: every step).
"""
from __future__ import annotations

import argparse
import sys

import torch
import user_tokens

from sumo_scendiff.model.diffusion import ScenarioDiffusion
from sumo_scendiff.tokens.encoding import FEATURE_SLICES, FEATURES, PRESENCE_SLICE

KINEMATICS = ("speed", "final_speed", "heading_to_final")


def without_kinematics(tokens: torch.Tensor) -> torch.Tensor:
    out = tokens.clone()
    for f in KINEMATICS:
        out[..., FEATURE_SLICES[f]] = 0.0
        out[..., PRESENCE_SLICE.start + FEATURES.index(f)] = 0.0
    return out


def patch(null: str, sigma_lo: float) -> None:
    original = ScenarioDiffusion.null_condition

    def null_condition(cond, guidance, scene_guidance, scene_guidance_sigma=0.0, density_guidance=None):
        unc, w, lo = original(cond, guidance, scene_guidance, scene_guidance_sigma, density_guidance)
        has = ~cond["agent_pad_mask"].all(dim=1)
        lo = torch.where(has, torch.tensor(float(sigma_lo)), lo)
        if null == "kinematics":
            unc = dict(unc, agent_tokens=without_kinematics(cond["agent_tokens"]),
                       agent_pad_mask=torch.where(has[:, None], cond["agent_pad_mask"], unc["agent_pad_mask"]),
                       global_token=torch.where(has[:, None], cond["global_token"], unc["global_token"]))
        return unc, w, lo
    ScenarioDiffusion.null_condition = staticmethod(null_condition)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    rest = argv[argv.index("--") + 1:] if "--" in argv else []
    own = argv[:argv.index("--")] if "--" in argv else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--null", choices=("map", "kinematics"), default="map")
    p.add_argument("--token-sigma-lo", type=float, default=0.0)
    o = p.parse_args(own)
    patch(o.null, o.token_sigma_lo)
    return user_tokens.main(user_tokens.get_options(rest))


if __name__ == "__main__":
    sys.exit(main())
