"""Export: a trained autoencoder and diffusion model as one ``scenario-diffusion`` checkpoint, the
file :class:`~sumo_scendiff.generation.generator.ScenarioGenerator` loads."""
from __future__ import annotations

from ..model import checkpoint as ckpt
from .loop import load_training


def _same_encoder(state: dict, exported: str) -> bool:
    """Whether ``state``'s encoder is the one of the exported model ``exported`` (to its float16
    rounding): a decoder fine-tuned from an earlier run of the same frozen encoder fits its diffusion
    model as well as one started from the exported file."""
    ck = ckpt.load(exported, ("autoencoder-train", "diffusion-train", "scenario-diffusion"))
    if ck["kind"] != "scenario-diffusion":
        return False
    theirs = ck["autoencoder"]
    mine = {k: v for k, v in state.items() if k.startswith("E.")}
    return bool(mine) and all(k in theirs and v.shape == theirs[k].shape and
                              bool((v.half() == theirs[k].half()).all()) for k, v in mine.items())


def export_model(autoencoder: str, diffusion: str, output: str, fp16: bool = False,
                 scene_guidance: float = 1.0, scene_guidance_sigma: float = 0.0) -> str:
    """Write ``output`` (atomically) from two training checkpoints; returns its SHA-256. Raises
    :class:`~sumo_scendiff.model.checkpoint.CheckpointError` for an unreadable input or a diffusion
    model trained in another autoencoder's latent space."""
    ae_ck = load_training(autoencoder, "autoencoder-train")
    df_ck = load_training(diffusion, "diffusion-train")
    # a decoder-only fine-tune (--freeze-encoder) keeps the latent space the diffusion was trained in
    if df_ck["autoencoder_sha256"] not in (ckpt.sha256(autoencoder), ae_ck.get("encoder_from_sha256")) \
            and not _same_encoder(ae_ck["state"], diffusion):
        raise ckpt.CheckpointError(f"{diffusion}: was trained on another autoencoder than {autoencoder}")

    def cast(state):
        return {k: (v.half() if fp16 and v.is_floating_point() else v) for k, v in state.items()}

    return ckpt.save(output, "scenario-diffusion",
                     autoencoder_config=ae_ck["model_config"], autoencoder=cast(ae_ck["state"]),
                     diffusion_config=df_ck["model_config"],
                     diffusion=cast(df_ck.get("ema", df_ck["state"])),  # the weight average when kept
                     latent_scale=float(df_ck["latent_scale"]),
                     scene_guidance=float(scene_guidance),
                     scene_guidance_sigma=float(scene_guidance_sigma),
                     # steps over every warm start (a run's own steps plus those it started from)
                     trained={"autoencoder_steps": ae_ck["step"] + ae_ck.get("steps_before", 0),
                              "diffusion_steps": df_ck["step"] + df_ck.get("steps_before", 0),
                              "diffusion_ema": "ema" in df_ck,
                              "autoencoder_val": ae_ck.get("best_val"),
                              "diffusion_val": df_ck.get("best_val"),
                              "data": df_ck.get("data_manifest")})
