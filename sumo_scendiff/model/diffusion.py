"""The latent diffusion model of section 3.2-3.3: map encoder E_m, conditional UNet M, EDM.

    model = ScenarioDiffusion(DiffusionConfig())
    loss = model.loss(z0, m, agent_tokens, agent_pad_mask, global_token)         # training
    z = model.sample(m, agent_tokens, agent_pad_mask, global_token, steps=10)    # inference

``z0`` is the autoencoder's latent (mu of E(x)) multiplied by ``latent_scale`` so that its standard
deviation matches sigma_data = 0.5 (latent-diffusion's scale factor); :meth:`sample` returns
latents in the same scaled units, divide by ``latent_scale`` before decoding.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import torch
from torch import Tensor, nn

from ..map.raster import MAP_CHANNELS
from ..tokens.encoding import P_MASK_BINS, token_region
from ..tokens.encoding import global_token as encode_global_token
from .autoencoder import ConvEncoder
from .edm import (
    EDMLoss,
    EDMPrecond,
    NoiseSampler,
    condition_guided,
    guided,
    initial_noise,
    inpainted,
    karras_sigmas,
    sample_dpmpp_2m,
)
from .unet import UNet, UNetConfig


# latent cells around a positioned token that its guidance reaches: its own and the next (a box
# centre near a cell's border, a vehicle longer than a cell)
TOKEN_REGION_CELLS = 1


@dataclass(frozen=True)
class DiffusionConfig:
    """E_m and the UNet. ``map_channels``: widths of E_m at 128, 64, 32, 16 px (appendix D.1)."""

    C_m: int = len(MAP_CHANNELS)  # E_m reads the first C_m map channels (11: no lane_dir*)
    map_channels: tuple[int, ...] = (16, 32, 64, 64)
    stem: str = "full"  # E_m's first layers (autoencoder.encoder_stem): "full" or "stride2"
    unet: UNetConfig = field(default_factory=UNetConfig)
    use_map: bool = True        # False: the paper's no-map ablation (m replaced by zeros)
    # training noise levels, log(sigma) ~ N(P_mean, P_std^2) (eq. 1; appendix D: -0.5 and 1, edm.P_MEAN
    # / P_STD): shifted up and widened, since map-only sampling lost agents at high sigma, where the
    # paper's levels put few training steps (docs/model.md)
    P_mean: float = 0.3
    P_std: float = 1.4


class ScenarioDiffusion(nn.Module):
    """D(z; sigma, c) with c = (E_m(m), agent tokens, global token), EDM-preconditioned."""

    def __init__(self, cfg: DiffusionConfig = DiffusionConfig()):
        super().__init__()
        self.cfg = cfg
        self.E_m = ConvEncoder(cfg.C_m, cfg.map_channels, cfg.unet.c_map, stem=cfg.stem)
        self.denoiser = EDMPrecond(UNet(cfg.unet))
        self.edm_loss = EDMLoss(p_mean=cfg.P_mean, p_std=cfg.P_std)

    def encode_map(self, m: Tensor) -> Tensor:
        m = m[:, : self.cfg.C_m]
        if not self.cfg.use_map:
            m = torch.zeros_like(m)
        return self.E_m(m)

    def cond(self, m: Tensor, agent_tokens: Tensor, agent_pad_mask: Tensor, global_token: Tensor) -> dict:
        return {"m_enc": self.encode_map(m), "agent_tokens": agent_tokens,
                "agent_pad_mask": agent_pad_mask, "global_token": global_token}

    def loss(self, z0: Tensor, m: Tensor, agent_tokens: Tensor, agent_pad_mask: Tensor,
             global_token: Tensor, generator: Optional[torch.Generator] = None,
             weight: Optional[Tensor] = None) -> Tensor:
        """Mean EDM loss (paper eq. 1) over the batch; ``weight`` (B, 1, R, R) weighs latent cells."""
        cond = self.cond(m, agent_tokens, agent_pad_mask, global_token)
        return self.edm_loss(self.denoiser, z0, cond=cond, generator=generator, weight=weight).mean()

    @staticmethod
    def null_condition(cond: dict, guidance: float, scene_guidance: float,
                       scene_guidance_sigma: float = 0.0, density_guidance: float | None = None
                       ) -> tuple[dict, Tensor, Tensor]:
        """The condition each example is guided away from, its weight and the noise level below
        which its guidance stops (each (B,)):

        * with agent tokens: the map alone (no token, p_mask = 1), weight ``guidance`` -- the
          tokens' agents are followed more closely;
        * without: the empty scene (no token, p_mask = 0: nothing to add), weight
          ``scene_guidance`` -- the global token's "add agents" is followed more closely, only
          while sigma > ``scene_guidance_sigma``: how many agents there are is decided at high
          noise; guiding the fine steps too pushes agents off their lanes.

        Without agent tokens but with a density, the weight is ``density_guidance`` (None: the
        same), and the density stays in the null: the weight amplifies the global token's "add
        agents" at the level the density asks for, not the density itself.

        Both nulls are conditions training shows the model (``p_map_only``; scenes whose every
        token is kept)."""
        pad, glob = cond["agent_pad_mask"], cond["global_token"]
        has_tokens = ~pad.all(dim=1)    # False for every example when the batch has no token at all
        g = {p: torch.from_numpy(encode_global_token(p, dim=glob.shape[-1])).to(glob).expand_as(glob)
             for p in (0.0, 1.0)}
        null_glob = torch.where(has_tokens[:, None], g[1.0], g[0.0])
        # the density condition stays in the null: the weight calibrated for p_mask's "add agents"
        # must not also amplify the density the user asked for
        null_glob[:, P_MASK_BINS:] = glob[:, P_MASK_BINS:]
        w = torch.where(has_tokens, torch.tensor(float(guidance)), torch.tensor(float(scene_guidance)))
        if density_guidance is not None and glob.shape[-1] > P_MASK_BINS:
            w = torch.where(~has_tokens & (glob[:, -1] > 0), torch.tensor(float(density_guidance)), w)
        sigma_lo = torch.where(has_tokens, torch.tensor(0.0), torch.tensor(float(scene_guidance_sigma)))
        return dict(cond, agent_pad_mask=torch.ones_like(pad), global_token=null_glob), w, sigma_lo

    def local_guidance(self, cond: dict, local: bool = True) -> tuple[Tensor, Tensor | None]:
        """The ``parallel`` weight (B,) and ``region`` (B, 1, R, R) of :func:`~.edm.guided`: for a
        window with agent tokens, the guidance only in the latent cells within
        :data:`TOKEN_REGION_CELLS` of a positioned token (the rest of the window is the
        conditional model's, which adds the traffic p_mask asks for; guided against the map alone
        it drew almost nothing beside the tokens), and without its part along the conditional
        estimate (plain guidance at 3 drew a token's vehicle faster than it asks). Windows
        without tokens keep the global token's plain guidance, as calibrated. ``local`` False:
        plain guidance everywhere."""
        pad = cond["agent_pad_mask"]
        has_tokens = ~pad.all(dim=1)
        if not local or not bool(has_tokens.any()):
            return torch.ones(len(pad)), None
        parallel = torch.where(has_tokens, 0.0, 1.0)
        return parallel, token_region(cond["agent_tokens"], pad, self.cfg.unet.res, TOKEN_REGION_CELLS)

    @torch.no_grad()
    def sample(self, m: Tensor, agent_tokens: Tensor, agent_pad_mask: Tensor, global_token: Tensor,
               steps: int = 10, sampler: Callable = sample_dpmpp_2m,
               generator: Optional[torch.Generator] = None, noise: Optional[Tensor] = None,
               guidance: float = 1.0, scene_guidance: float = 1.0,
               scene_guidance_sigma: float = 0.0, density_guidance: float | None = None,
               local: bool = True, signal_guidance: float = 1.0,
               known: Optional[tuple[Tensor, Tensor]] = None,
               noise_sampler: Optional[NoiseSampler] = None) -> Tensor:
        """Integrate the probability-flow ODE from sigma_max to 0 (paper eq. 3), or its SDE with a
        stochastic sampler; returns z (scaled).

        ``noise``: standard-normal (B, C_z, R, R) starting noise (scaled by sigma_max here); drawn
        with ``generator`` when not given. Classifier-free guidance (:meth:`null_condition`):
        ``guidance`` for examples with agent tokens, ``scene_guidance`` for those without (at
        sigma > ``scene_guidance_sigma`` only); a weight of 1 is off. A guided step costs an example
        two UNet passes. ``local``: the tokens' guidance as :meth:`local_guidance` says, not
        the paper's over the whole window. ``signal_guidance``: the weight of the traffic lights'
        map channels against the same map without them (:func:`~.edm.condition_guided`; the
        model is trained both ways, ``p_no_signals``), applied to both branches of the guidance
        above: twice the UNet passes, for a batch where some window shows a light's state.
        ``known``: ``(z_known, mask)``, latent cells fixed to z_known where mask is 1 and generated
        around them (:func:`~.edm.inpainted`; pinned tokens). ``noise_sampler``: the stochastic
        samplers' fresh noise per step (:mod:`.edm`; from ``generator`` when not given).
        """
        cfg = self.cfg.unet
        cond = self.cond(m, agent_tokens, agent_pad_mask, global_token)
        denoiser = self.denoiser
        null, w, sigma_lo = self.null_condition(cond, guidance, scene_guidance, scene_guidance_sigma,
                                                density_guidance)
        parallel, region = self.local_guidance(cond, local)
        signals = [MAP_CHANNELS.index("signal_go"), MAP_CHANNELS.index("signal_stop")]
        if signal_guidance != 1.0 and m.shape[1] >= len(MAP_CHANNELS) and self.cfg.C_m >= len(MAP_CHANNELS) \
                and bool(m[:, signals].any()):
            dark = m.clone()
            dark[:, signals] = 0.0      # what training shows for lights unknown
            m_dark = self.encode_map(dark)
            cond, null = dict(cond, m_enc_null=m_dark), dict(null, m_enc_null=m_dark)
            denoiser = condition_guided(denoiser, "m_enc", signal_guidance)
        if bool((w != 1.0).any()):
            denoiser, cond = guided(denoiser, cond, null, w, sigma_lo, parallel, region), None
        if known is not None:
            denoiser = inpainted(denoiser, *known)
        sigmas = karras_sigmas(steps, device=m.device)
        if noise is None:
            z_t = initial_noise((m.shape[0], cfg.c_z, cfg.res, cfg.res), generator=generator,
                                device=m.device)
        else:
            z_t = noise.to(m.device) * sigmas[0]
        return sampler(denoiser, z_t, sigmas, cond=cond, generator=generator, noise_sampler=noise_sampler)
