"""Scenario autoencoder: E(x) -> z,  D(z, m) = D_up(z, D_down(m)) -> y (paper section 3.1, appendix C).

Architecture after the latent-diffusion autoencoder (appendix C.1), one ResnetBlock per
resolution, narrowed for CPU training and without the mid-block self-attention:

* E:      x (B, 15, 128, 128) -> (mu, logvar), each (B, C_z, 16, 16)     (f = 3)
* D_down: m (B, C_m, 128, 128) -> (B, C_map, 16, 16), same architecture as E, own weights
* D_up:   concat(z, D_down(m)) at 16 -> upsample 16 -> 32 -> 64 -> y (B, 19 [+ 2K], 64, 64); the output
  resolution is truncated at 64 px as in appendix C.1. See ``detection.py`` for the layout of y.
  Beyond the paper, D_down's 32 and 64 px features are added (1x1 projections) into D_up at those
  resolutions, U-Net fashion, so the decoder sees the lanes finer than the 16 px bottleneck's
  6.25 m cells (docs/model.md: a small gain in lane heading).
  With ``C_t`` > 0 (beyond the paper) D_up also reads the positioned agent tokens as a 64 px raster
  (``tokens/raster.py``), pooled to and added (3x3 convolutions) at 16, 32 and 64 px, so a vehicle
  decoded under a token can take the speed, turn and size it gives, which the 4-channel latent
  carries only roughly: D(z, m, t); a token branch (``token_branch``) corrects the outputs in the
  cells a token covers and draws its vehicle's steps toward the token's speeds.

Training objective (appendix C.3): L = L_rec + kl_weight * L_KL, both per-scene sums averaged
over the batch.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from ..map.raster import MAP_CHANNELS
from ..tokens.raster import C_T, SPEED_SCALE, TOKEN_CHANNELS, token_raster
from .blocks import Downsample, ResnetBlock, Upsample, group_norm, unused
from .detection import C_Y, DetectionLossConfig, detection_loss
from .heading import bin_width


# D_down reads the map channels up to the traffic lights' states: where a vehicle stands at red is
# the diffusion model's to draw (its E_m reads them); the decoder only puts the boxes on the lanes
AE_MAP_CHANNELS = MAP_CHANNELS.index("signal_go")


@dataclass(frozen=True)
class AutoencoderConfig:
    """Hyper-parameters of :class:`ScenarioAutoencoder` (names follow the paper's symbols); the
    defaults are the shipped model's (docs/model.md)."""

    C_x: int = 15  # agent raster channels (appendix A)
    C_m: int = AE_MAP_CHANNELS  # map raster channels D_down reads (the first C_m)
    C_z: int = 4  # latent channels
    C_map: int = 16  # channels of D_down(m)
    enc_channels: tuple[int, ...] = (16, 32, 64, 64)  # E and D_down, at 128, 64, 32, 16 px
    stem: str = "full"  # E's and D_down's first layers (encoder_stem): "full" or "stride2"
    dec_channels: tuple[int, ...] = (64, 32, 32)  # D_up, at 16, 32, 64 px (CPU budget)
    dropout: float = 0.0
    kl_weight: float = 0.01  # appendix C.3 has 0.1: the latent was then too noisy to place boxes
    # scale of the reparameterisation noise in training: 1 is the VAE's z = mu + sigma * eps; 0 decodes
    # mu itself, the latents the diffusion model learns (the recipe's decoder stage, encoder frozen)
    latent_noise: float = 0.0
    logit_bias: float = -4.0  # initial box logit (prior probability ~ 0.018)
    log_dist_bias: float = 0.4  # initial log edge distance (~1.5 m)
    delta_scale: tuple[float, float, float] = (10.0, 2.0, 0.3)  # output units of (dx m, dy m, dyaw rad)
    use_map: bool = True  # False: the paper's no-map ablation (D sees m replaced by zeros)
    # beyond the paper: K > 0 adds a MultiBin heading head of K bins (2K output channels, heading.py)
    # that commits to one heading where the cos/sin regression would average between lanes
    heading_bins: int = 16
    # beyond the paper: C_t > 0 gives D_up the agent tokens as a raster of C_t channels
    # (tokens.raster.C_T); 0 = the paper's D(z, m), which decodes from the latent alone
    C_t: int = C_T
    # with C_t: channels of a token branch (0: none), a small stack at the output resolution that
    # reads the decoder's last features beside the token raster and corrects the head's outputs in
    # the cells a token covers only (gated by the raster's token channel): a scene without tokens,
    # and every cell away from one, decodes as the decoder alone, while a token's own vehicle gets
    # layers of its own to follow it, and a gate that draws its steps toward the token's speeds
    token_branch: int = 32
    loss: DetectionLossConfig = field(default_factory=DetectionLossConfig)


# ConvEncoder's stems (AutoencoderConfig.stem, DiffusionConfig.stem): "full" is the paper's conv_in and
# a first level at the raster's full resolution; "stride2" reads the raster with one stride-2
# convolution straight to the first level's width at half resolution (docs/training.md)
STEMS = ("full", "stride2")


def encoder_stem(stem: str, in_ch: int, ch: int, dropout: float = 0.0) -> tuple[nn.Module, list[nn.Module]]:
    """``(conv_in, first level)`` of a :class:`ConvEncoder` whose first width is ``ch``.

    "full": a 3x3 conv_in, then the first level's ResnetBlock and Downsample at full resolution.
    "stride2": one stride-2 3x3 convolution and no first-level layers: the blocks at full
    resolution are the slowest per FLOP on CPU, and the decoder reads none of their features
    (its map skips are at 32 and 64 px), so the encoder starts at half resolution and its
    output, latent and skips keep their shapes."""
    if stem == "full":
        return nn.Conv2d(in_ch, ch, 3, padding=1), [ResnetBlock(ch, ch, dropout=dropout), Downsample(ch)]
    if stem == "stride2":
        return nn.Conv2d(in_ch, ch, 3, stride=2, padding=1), []
    raise ValueError(f"unknown encoder stem {stem!r} (one of {', '.join(STEMS)})")


class ConvEncoder(nn.Module):
    """LDM-style encoder: conv_in, [ResnetBlock, Downsample] per level, mid ResnetBlock, GN-SiLU-conv_out.

    Downsamples by 2^(len(channels) - 1). Used for E (out_ch = 2 C_z) and D_down (out_ch = C_map).
    ``stem`` (:func:`encoder_stem`): "stride2" replaces conv_in and the first level by one stride-2
    convolution; the output's shape is the same.
    """

    def __init__(self, in_ch: int, channels: tuple[int, ...], out_ch: int, dropout: float = 0.0,
                 stem: str = "full"):
        super().__init__()
        if len(channels) < 2:  # the stem is the first level's (and its Downsample's)
            raise ValueError(f"a ConvEncoder needs two levels or more, not {len(channels)}")
        self.stem = stem
        self.conv_in, layers = encoder_stem(stem, in_ch, channels[0], dropout)
        prev = channels[0]
        for i, ch in enumerate(channels[1:], start=1):
            layers.append(ResnetBlock(prev, ch, dropout=dropout))
            if i < len(channels) - 1:
                layers.append(Downsample(ch))
            prev = ch
        layers.append(ResnetBlock(prev, prev, dropout=dropout))  # mid block
        self.body = nn.Sequential(*layers)
        self.norm_out = group_norm(prev)
        self.conv_out = nn.Conv2d(prev, out_ch, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv_out(F.silu(self.norm_out(self.body(self.conv_in(x)))))

    def pyramid(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """``(forward(x), features)``: also the features entering each Downsample, finest first,
        ``(B, channels[i], H / 2^i, W / 2^i)``; with the "stride2" stem the first is the stem's
        output, ``(B, channels[0], H / 2, W / 2)`` (the decoder reads only the 32 and 64 px ones)."""
        h = self.conv_in(x)
        feats = [h] if self.stem == "stride2" else []  # the place of the first level's, which it has not
        for layer in self.body:
            if isinstance(layer, Downsample):
                feats.append(h)
            h = layer(h)
        return self.conv_out(F.silu(self.norm_out(h))), feats


class DetectionDecoder(nn.Module):
    """D_up: (z, D_down(m)) -> y. conv_in, mid ResnetBlock, [ResnetBlock, Upsample] per level, head.

    The head's raw outputs are multiplied by fixed per-channel scales so that y is in physical
    units (metres / radians) while the network works with O(1) numbers.
    """

    def __init__(self, cfg: AutoencoderConfig):
        super().__init__()
        ch = cfg.dec_channels
        self.conv_in = nn.Conv2d(cfg.C_z + cfg.C_map, ch[0], 3, padding=1)
        layers = [ResnetBlock(ch[0], ch[0], dropout=cfg.dropout)]  # mid block
        prev = ch[0]
        for i, c in enumerate(ch):
            layers.append(ResnetBlock(prev, c, dropout=cfg.dropout))
            if i < len(ch) - 1:
                layers.append(Upsample(c))
            prev = c
        # D_down's features at 16 * 2^i px (its level top - i) are projected (1x1) and added to the
        # input of the ResnetBlock of level i >= 1 (body index 1 + 2 i), U-Net fashion, so the boxes
        # follow the lanes finer than the 16 px bottleneck's 6.25 m cells
        top = len(cfg.enc_channels) - 1
        self.skip_at, self.skips = {}, nn.ModuleDict()
        for i in range(1, len(ch)):
            self.skip_at[1 + 2 * i] = top - i
            self.skips[str(1 + 2 * i)] = nn.Conv2d(cfg.enc_channels[top - i], ch[i - 1], 1)
        # with C_t, the token raster (at the output resolution) is average-pooled to each level's
        # resolution and added (3x3) to the input of that level's ResnetBlock, body index 1 + 2 i
        self.token_at, self.tokens = {}, nn.ModuleDict()
        for i in range(len(ch)) if cfg.C_t else ():
            self.token_at[1 + 2 * i] = 2 ** (len(ch) - 1 - i)
            self.tokens[str(1 + 2 * i)] = nn.Conv2d(cfg.C_t, ch[max(i - 1, 0)], 3, padding=1)
        self.body = nn.Sequential(*layers)
        self.norm_out = group_norm(prev)
        k = cfg.heading_bins
        self.conv_out = nn.Conv2d(prev, C_Y + 2 * k, 3, padding=1)
        self.branch = TokenBranch(prev, cfg.C_t, cfg.token_branch, C_Y + 2 * k, cfg.delta_scale[0],
                                  cfg.dropout) if cfg.C_t and cfg.token_branch else None
        scale = torch.ones(C_Y + 2 * k)
        scale[7:C_Y] = torch.tensor(cfg.delta_scale).repeat(4)
        if k:
            scale[C_Y + k:] = bin_width(k)  # residuals in units of the bin width
        self.register_buffer("out_scale", scale[:, None, None], persistent=False)
        with torch.no_grad():
            self.conv_out.bias.zero_()
            self.conv_out.bias[0] = cfg.logit_bias
            self.conv_out.bias[3:7] = cfg.log_dist_bias

    def forward(self, z: torch.Tensor, m_enc: torch.Tensor, m_feats: list[torch.Tensor],
                t: torch.Tensor | None = None) -> torch.Tensor:
        """``m_feats``: D_down's pyramid (finest first); ``t``: the token raster (B, C_t, 64, 64) of
        a decoder with C_t (None: no tokens)."""
        h = self.conv_in(torch.cat([z, m_enc], dim=1))
        for k, layer in enumerate(self.body):
            if k in self.skip_at:
                h = h + self.skips[str(k)](m_feats[self.skip_at[k]])
            if t is not None and k in self.token_at:
                f = self.token_at[k]
                h = h + self.tokens[str(k)](F.avg_pool2d(t, f) if f > 1 else t)
            h = layer(h)
        y = self.conv_out(F.silu(self.norm_out(h)))
        if self.branch is not None and t is not None:
            y = self.branch(y, h, t)
        return y * self.out_scale


MIX_STEPS = (-2, -1, 1, 2)                      # s: the 1 s steps, in model/detection.py's order
DX_CHANNEL = {s: 7 + 3 * i for i, s in enumerate(MIX_STEPS)}   # each step's dx: (dx, dy, dyaw) from channel 7
MIX_GAIN = 10.0                                 # gate logits = MIX_GAIN x the conv: Adam's steps move it 10x
MIX_GATE_START = -2.0                           # sigmoid(-2) = 0.12: open enough to learn from, closed enough to start near the branch


class TokenBranch(nn.Module):
    """The head's outputs corrected where a token stands (``AutoencoderConfig.token_branch``):
    conv over [features, token raster], two ResnetBlocks, GN-SiLU-conv, added to the head's raw
    outputs in the cells whose token channel is set and nowhere else; then each step's dx is drawn
    toward the token's speeds through a gate read from the same features (:meth:`_mixed`): a
    correction added to y must know y to undo it, which the branch's normalised layers do not read."""

    def __init__(self, feat_ch: int, c_t: int, ch: int, out_ch: int, mix_scale: float, dropout: float = 0.0):
        super().__init__()
        self.conv_in = nn.Conv2d(feat_ch + c_t, ch, 3, padding=1)
        self.blocks = nn.Sequential(ResnetBlock(ch, ch, dropout=dropout), ResnetBlock(ch, ch, dropout=dropout))
        self.norm_out = group_norm(ch)
        # the correction starts at zero (a residual branch: the head learns the cells first) ...
        self.conv_out = nn.Conv2d(ch, out_ch, 3, padding=1)
        nn.init.zeros_(self.conv_out.weight)
        nn.init.zeros_(self.conv_out.bias)
        # ... and each 1 s step's gate near closed (open enough to learn from)
        self.mix_scale = mix_scale
        self.mix = nn.Conv2d(ch, len(MIX_STEPS), 3, padding=1)
        nn.init.zeros_(self.mix.weight)
        nn.init.constant_(self.mix.bias, MIX_GATE_START / MIX_GAIN)

    def forward(self, y: torch.Tensor, h: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        gate = t[:, :1] > 0          # tokens.raster: channel 0 is 1 in the cells around each token
        if not bool(gate.any()):     # no token in the batch: y itself, with the gradients the full path
            return y + unused(self)  # gives (a map-only stage skips a fifth of its step)
        return self._corrected(y, h, t, gate)

    def _corrected(self, y: torch.Tensor, h: torch.Tensor, t: torch.Tensor, gate: torch.Tensor) -> torch.Tensor:
        f = F.silu(self.norm_out(self.blocks(self.conv_in(torch.cat([h, t], dim=1)))))
        out = self._mixed(y + self.conv_out(f), t, torch.sigmoid(MIX_GAIN * self.mix(f)))
        return torch.where(gate, out, y)     # exactly y away from the tokens

    def _mixed(self, y: torch.Tensor, t: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """dx of each step drawn toward the step a vehicle at the token's speeds drives straight on:
        the past steps at its speed now, the future ones from it to its speed at +2 s (an absent one
        reads the other's, :meth:`ScenarioAutoencoder.token_raster`); the token raster's speeds are in
        ``SPEED_SCALE`` m/s, the head's dx in ``mix_scale`` m."""
        now = t[:, TOKEN_CHANNELS.index("speed")] * SPEED_SCALE / self.mix_scale
        final = t[:, TOKEN_CHANNELS.index("final_speed")] * SPEED_SCALE / self.mix_scale
        # past deltas are pose(t) - pose(t + 1): backward along the heading
        steps = {-2: -now, -1: -now, 1: 0.5 * (now + final), 2: final}
        chans = list(y.unbind(1))
        for k, step in enumerate(MIX_STEPS):
            ch = DX_CHANNEL[step]
            chans[ch] = (1 - g[:, k]) * chans[ch] + g[:, k] * steps[step]
        return torch.stack(chans, 1)


class ScenarioAutoencoder(nn.Module):
    """The scenario VAE of section 3.1: encoder E, map encoder D_down, decoder D_up."""

    def __init__(self, cfg: AutoencoderConfig = AutoencoderConfig()):
        super().__init__()
        self.cfg = cfg
        self.E = ConvEncoder(cfg.C_x, cfg.enc_channels, 2 * cfg.C_z, cfg.dropout, cfg.stem)
        self.D_down = ConvEncoder(cfg.C_m, cfg.enc_channels, cfg.C_map, cfg.dropout, cfg.stem)
        self.D_up = DetectionDecoder(cfg)

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x (B, C_x, H, W) -> (mu, logvar), each (B, C_z, H / 2^f, W / 2^f)."""
        mu, logvar = self.E(x).chunk(2, dim=1)
        return mu, logvar.clamp(-30.0, 20.0)

    def sample(self, mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
        """Reparameterised z = mu + sigma * eps (sigma scaled by ``latent_noise``)."""
        return mu + self.cfg.latent_noise * torch.exp(0.5 * logvar) * torch.randn_like(mu)

    @property
    def out_res(self) -> int:
        """Side of y's grid (and of the token raster): the latent's 16 px doubled per D_up level."""
        return 16 * 2 ** (len(self.cfg.dec_channels) - 1)

    def token_raster(self, tokens: torch.Tensor, pad: torch.Tensor, exact: torch.Tensor | None = None) -> torch.Tensor:
        """The decoder's input ``t`` of agent tokens (B, T, AGENT_TOKEN_DIM) and their padding (B, T):
        ``tokens.raster.token_raster`` at the output resolution, in this decoder's encoding
        (``exact``: the tokens' exact speeds and turn, ``tokens.raster.exact_values``).

        A token giving only one of speed / final speed shows the decoder that value in the other's
        channel too (its presence bit still 0): with absent read as 0 m/s, a decoder learns the two
        channels' difference as the vehicle's acceleration and draws a token that gives only its
        speed braking from too fast (docs/tokens.md)."""
        return token_raster(tokens, pad, self.out_res, fill_speeds=True, exact=exact)

    def decode(self, z: torch.Tensor, m: torch.Tensor, t: torch.Tensor | None = None) -> torch.Tensor:
        """y = D(z, m) = D_up(z, D_down(m)), (B, 19 [+ 2 heading_bins], 64, 64). ``t``: the token
        raster (:meth:`token_raster`), read by a decoder with C_t > 0, else ignored."""
        m = m[:, : self.cfg.C_m]
        t = t if self.cfg.C_t else None
        if not self.cfg.use_map:
            m = torch.zeros_like(m)
        return self.D_up(z, *self.D_down.pyramid(m), t=t)

    def forward(self, x: torch.Tensor, m: torch.Tensor, sample: bool | None = None,
                t: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> (y, mu, logvar). z is sampled in training mode (or if ``sample``), else z = mu."""
        mu, logvar = self.encode(x)
        sample = self.training if sample is None else sample
        z = self.sample(mu, logvar) if sample else mu
        return self.decode(z, m, t), mu, logvar

    @staticmethod
    def kl(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
        """KL(q(z|x) || N(0, I)) summed over the latent, averaged over the batch."""
        return 0.5 * (mu.square() + logvar.exp() - 1.0 - logvar).flatten(1).sum(1).mean()

    def loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Batch with keys x, m, boxes, traj, traj_mask, valid (and t, the token raster, for a
        decoder with C_t; told, the boxes whose token gives a speed) -> dict of loss terms.

        Keys: the detection terms (cls_pos, cls_neg, box, vertex, traj_pos, traj_yaw, rec), the
        diagnostic ``matched``, ``kl`` (unweighted) and ``total`` = rec + kl_weight * kl.
        """
        y, mu, logvar = self(batch["x"], batch["m"], t=batch.get("t"))
        out = detection_loss(y, batch["boxes"], batch["traj"], batch["traj_mask"], batch["valid"],
                             self.cfg.loss, junction=batch["m"][:, MAP_CHANNELS.index("junction")],
                             told=batch.get("told"))
        out["kl"] = self.kl(mu, logvar)
        out["total"] = out["rec"] + self.cfg.kl_weight * out["kl"]
        return out
