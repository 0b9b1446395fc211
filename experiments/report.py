"""Shared by the experiment scripts: the model options and loading, and a markdown report printed and,
with ``-o``, written to a file (as benchmarks/report.py's)."""
from __future__ import annotations

import os


def emit(text: str, output: str | None, title: str) -> None:
    print(text)
    if output:
        os.makedirs(os.path.dirname(os.path.abspath(output)), exist_ok=True)
        with open(output, "w") as f:
            f.write(f"# {title}\n\n{text}")


def add_model_options(p, autoencoder_help: str) -> None:
    """``--checkpoint`` (a scenario-diffusion checkpoint) and ``--autoencoder`` (a training run's)."""
    p.add_argument("--checkpoint", default=None, help="scenario-diffusion checkpoint (default: shipped)")
    p.add_argument("--autoencoder", default=None, help=f"an autoencoder training checkpoint: {autoencoder_help}")


def load_models(checkpoint: str | None, autoencoder: str | None):
    """``(generator, autoencoder, name, sha256)``: the scenario-diffusion checkpoint (default: the
    shipped one), or with ``autoencoder`` that training run's (or exported model's) autoencoder alone
    (generator None).
    The autoencoder is in eval mode."""
    from sumo_scendiff.generation.generator import ScenarioGenerator
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
    if autoencoder:
        from sumo_scendiff.train.loop import (
            load_training,  # a run's last.pt, or an exported model's half
        )
        try:
            ck = load_training(autoencoder, "autoencoder-train")
        except ckpt.CheckpointError as e:
            raise SystemExit(str(e))
        ae = ScenarioAutoencoder(ckpt.config_from_dict(AutoencoderConfig, ck["model_config"]))
        ckpt.load_state(ae, ck["state"], autoencoder)
        gen, name, sha = None, f"{autoencoder} (step {ck['step']})", ckpt.sha256(autoencoder)
    else:
        gen = ScenarioGenerator.load(checkpoint)
        ae, name, sha = gen.ae, checkpoint or "shipped", gen.sha256
    return gen, ae.eval(), name, sha
