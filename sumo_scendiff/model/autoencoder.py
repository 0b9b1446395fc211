"""Scenario autoencoder: E(x) -> z,  D(z, m) = D_up(z, D_down(m)) -> y (paper section 3.1, appendix C).

Architecture after the latent-diffusion autoencoder (appendix C.1), one ResnetBlock per
resolution, narrowed for CPU training and without the mid-block self-attention:

* E:      x (B, 15, 128, 128) -> (mu, logvar), each (B, C_z, 16, 16)     (f = 3)
* D_down: m (B, C_m, 128, 128) -> (B, C_map, 16, 16), same architecture as E, own weights
* D_up:   concat(z, D_down(m)) at 16 -> upsample 16 -> 32 -> 64 -> y (B, 19 [+ 2K], 64, 64); the output
  resolution is truncated at 64 px as in appendix C.1. See ``detection.py`` for the layout of y.
  With ``map_skips`` (beyond the paper) D_down's 32 and 64 px features are added (1x1 projections)
  into D_up at those resolutions, U-Net fashion, so the decoder sees the lanes finer than the 16 px
  bottleneck's 6.25 m cells (docs/model.md: a small gain in lane heading).
  With ``C_t`` > 0 (beyond the paper) D_up also reads the positioned agent tokens as a 64 px raster
  (``tokens/raster.py``), pooled to and added (3x3 convolutions) at 16, 32 and 64 px, so a vehicle
  decoded under a token can take the speed, turn and size it gives, which the 4-channel latent
  carries only roughly: D(z, m, t).

Training objective (appendix C.3): L = L_rec + kl_weight * L_KL, both per-scene sums averaged
over the batch.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from ..map.raster import MAP_CHANNELS
from ..tokens.raster import SPEED_SCALE, TOKEN_CHANNELS, token_raster
from .blocks import Downsample, ResnetBlock, Upsample, group_norm, grow_segments
from .detection import C_Y, DetectionLossConfig, detection_loss
from .heading import bin_width


@dataclass(frozen=True)
class AutoencoderConfig:
    """Hyper-parameters of :class:`ScenarioAutoencoder` (names follow the paper's symbols)."""

    C_x: int = 15  # agent raster channels (appendix A)
    C_m: int = len(MAP_CHANNELS)  # map raster channels: D_down reads the first C_m (11: no lane_dir*)
    C_z: int = 4  # latent channels
    C_map: int = 16  # channels of D_down(m)
    enc_channels: tuple[int, ...] = (16, 32, 64, 64)  # E and D_down, at 128, 64, 32, 16 px
    dec_channels: tuple[int, ...] = (64, 32, 32)  # D_up, at 16, 32, 64 px (CPU budget)
    dropout: float = 0.0
    kl_weight: float = 0.1  # appendix C.3
    # scale of the reparameterisation noise in training: 1 is the VAE's z = mu + sigma * eps; a
    # decoder-only fine-tune may lower it to sharpen the decoding of mu (the latents diffusion learns)
    latent_noise: float = 1.0
    logit_bias: float = -4.0  # initial box logit (prior probability ~ 0.018)
    log_dist_bias: float = 0.4  # initial log edge distance (~1.5 m)
    delta_scale: tuple[float, float, float] = (10.0, 2.0, 0.3)  # output units of (dx m, dy m, dyaw rad)
    # beyond appendix C.1: D_up also receives D_down's features at 32 and 64 px (U-Net skips), so
    # that boxes can follow the lanes at the output resolution, not only through the 16 px bottleneck
    map_skips: bool = False
    use_map: bool = True  # False: the paper's no-map ablation (D sees m replaced by zeros)
    # beyond the paper: K > 0 adds a MultiBin heading head of K bins (2K output channels, heading.py)
    # that commits to one heading where the cos/sin regression would average between lanes
    heading_bins: int = 0
    # beyond the paper: C_t > 0 gives D_up the agent tokens as a raster of C_t channels
    # (tokens.raster.C_T); 0 = the paper's D(z, m), which decodes from the latent alone
    C_t: int = 0
    # with C_t: a token giving only one of speed / final speed shows the decoder that value in the
    # other's channel too (its presence bit still 0). With absent read as 0 m/s, a decoder learns
    # the two channels' difference as the vehicle's acceleration and draws a token that gives only
    # its speed braking from too fast (docs/tokens.md)
    token_speeds_filled: bool = False
    # with C_t: channels of a token branch (0: none), a small stack at the output resolution that
    # reads the decoder's last features beside the token raster and corrects the head's outputs in
    # the cells a token covers only (gated by the raster's token channel, its last convolution
    # zero-initialised): a scene without tokens, and every cell away from one, decodes exactly as
    # the decoder it was added to, while a token's own vehicle gets layers of its own to follow it
    token_branch: int = 0
    # with token_branch: the branch also draws each 1 s step's length toward the token's speeds,
    # y' = (1 - g) y + g v, v the step a vehicle at the token's speed (now, +2 s) drives straight on
    # and g in (0, 1) a gate the branch learns (starting near 0). A correction added to y must know
    # y to undo it; the decoder's latent and map pull a token's vehicle toward the lane's limit by an
    # amount the branch's normalised layers cannot read, and a gate's gradient has one sign whether
    # the latent's speed is above or below the token's
    token_branch_mix: bool = False
    loss: DetectionLossConfig = field(default_factory=DetectionLossConfig)


class ConvEncoder(nn.Module):
    """LDM-style encoder: conv_in, [ResnetBlock, Downsample] per level, mid ResnetBlock, GN-SiLU-conv_out.

    Downsamples by 2^(len(channels) - 1). Used for E (out_ch = 2 C_z) and D_down (out_ch = C_map).
    """

    def __init__(self, in_ch: int, channels: tuple[int, ...], out_ch: int, dropout: float = 0.0):
        super().__init__()
        self.conv_in = nn.Conv2d(in_ch, channels[0], 3, padding=1)
        layers, prev = [], channels[0]
        for i, ch in enumerate(channels):
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
        ``(B, channels[i], H / 2^i, W / 2^i)``."""
        h, feats = self.conv_in(x), []
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
        # with map_skips, D_down's features at 16 * 2^i px (its level top - i) are projected (1x1)
        # and added to the input of the ResnetBlock of level i >= 1 (body index 1 + 2 i); the
        # projections start at zero, so a decoder warm-started from one without skips begins as it
        top = len(cfg.enc_channels) - 1
        self.skip_at, self.skips = {}, nn.ModuleDict()
        for i in range(1, len(ch)) if cfg.map_skips else ():
            self.skip_at[1 + 2 * i] = top - i
            self.skips[str(1 + 2 * i)] = conv = nn.Conv2d(cfg.enc_channels[top - i], ch[i - 1], 1)
            nn.init.zeros_(conv.weight)
            nn.init.zeros_(conv.bias)
        # with C_t, the token raster (at the output resolution) is average-pooled to each level's
        # resolution and added (3x3, zero-initialised: a decoder warm-started without it begins as
        # it was) to the input of that level's ResnetBlock, body index 1 + 2 i
        self.token_at, self.tokens = {}, nn.ModuleDict()
        for i in range(len(ch)) if cfg.C_t else ():
            self.token_at[1 + 2 * i] = 2 ** (len(ch) - 1 - i)
            self.tokens[str(1 + 2 * i)] = conv = nn.Conv2d(cfg.C_t, ch[max(i - 1, 0)], 3, padding=1)
            nn.init.zeros_(conv.weight)
            nn.init.zeros_(conv.bias)
        self.body = nn.Sequential(*layers)
        self.norm_out = group_norm(prev)
        k = cfg.heading_bins
        self.conv_out = nn.Conv2d(prev, C_Y + 2 * k, 3, padding=1)
        self.branch = TokenBranch(prev, cfg.C_t, cfg.token_branch, C_Y + 2 * k, cfg.dropout,
                                  mix_scale=cfg.delta_scale[0] if cfg.token_branch_mix else None) \
            if cfg.C_t and cfg.token_branch else None
        scale = torch.ones(C_Y + 2 * k)
        scale[7:C_Y] = torch.tensor(cfg.delta_scale).repeat(4)
        if k:
            scale[C_Y + k:] = bin_width(k)  # residuals in units of the bin width
        self.register_buffer("out_scale", scale[:, None, None], persistent=False)
        with torch.no_grad():
            self.conv_out.bias.zero_()
            self.conv_out.bias[0] = cfg.logit_bias
            self.conv_out.bias[3:7] = cfg.log_dist_bias

    def forward(self, z: torch.Tensor, m_enc: torch.Tensor,
                m_feats: list[torch.Tensor] | None = None, t: torch.Tensor | None = None) -> torch.Tensor:
        """``m_feats``: D_down's pyramid (finest first), needed with ``map_skips``; ``t``: the token
        raster (B, C_t, 64, 64) of a decoder with C_t (None: no tokens)."""
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
    conv over [features, token raster], two ResnetBlocks, GN-SiLU-conv (zero-initialised), added to
    the head's raw outputs in the cells whose token channel is set and nowhere else. With
    ``mix_scale`` (``token_branch_mix``) each step's dx is then drawn toward the token's speeds
    through a gate read from the same features (:meth:`_mixed`)."""

    def __init__(self, feat_ch: int, c_t: int, ch: int, out_ch: int, dropout: float = 0.0,
                 mix_scale: float | None = None):
        super().__init__()
        self.conv_in = nn.Conv2d(feat_ch + c_t, ch, 3, padding=1)
        self.blocks = nn.Sequential(ResnetBlock(ch, ch, dropout=dropout), ResnetBlock(ch, ch, dropout=dropout))
        self.norm_out = group_norm(ch)
        self.conv_out = nn.Conv2d(ch, out_ch, 3, padding=1)
        nn.init.zeros_(self.conv_out.weight)
        nn.init.zeros_(self.conv_out.bias)
        # token_branch_mix: one gate per 1 s step, read from the branch's features; near 0 at first
        self.mix_scale, self.mix = mix_scale, None
        if mix_scale is not None:
            self.mix = nn.Conv2d(ch, len(MIX_STEPS), 3, padding=1)
            nn.init.zeros_(self.mix.weight)
            nn.init.constant_(self.mix.bias, MIX_GATE_START / MIX_GAIN)

    def forward(self, y: torch.Tensor, h: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        gate = t[:, :1] > 0          # tokens.raster: channel 0 is 1 in the cells around each token
        if not self.training and not bool(gate.any()):   # (in training always run: DDP wants every weight used)
            return y
        f = F.silu(self.norm_out(self.blocks(self.conv_in(torch.cat([h, t], dim=1)))))
        out = y + self.conv_out(f)
        if self.mix is not None:
            out = self._mixed(out, t, torch.sigmoid(MIX_GAIN * self.mix(f)))
        return torch.where(gate, out, y)     # exactly y away from the tokens

    def _mixed(self, y: torch.Tensor, t: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """dx of each step drawn toward the step a vehicle at the token's speeds drives straight on:
        the past steps at its speed now, the future ones from it to its speed at +2 s (with
        ``token_speeds_filled`` an absent one reads the other's); the token raster's speeds are in
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
        self.E = ConvEncoder(cfg.C_x, cfg.enc_channels, 2 * cfg.C_z, cfg.dropout)
        self.D_down = ConvEncoder(cfg.C_m, cfg.enc_channels, cfg.C_map, cfg.dropout)
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
        (``exact``: the tokens' exact speeds and turn, ``tokens.raster.exact_values``)."""
        return token_raster(tokens, pad, self.out_res, fill_speeds=self.cfg.token_speeds_filled, exact=exact)

    def decode(self, z: torch.Tensor, m: torch.Tensor, t: torch.Tensor | None = None) -> torch.Tensor:
        """y = D(z, m) = D_up(z, D_down(m)), (B, 19 [+ 2 heading_bins], 64, 64). ``t``: the token
        raster (:meth:`token_raster`), read by a decoder with C_t > 0, else ignored."""
        m = m[:, : self.cfg.C_m]
        t = t if self.cfg.C_t else None
        if not self.cfg.use_map:
            m = torch.zeros_like(m)
        if self.cfg.map_skips:
            return self.D_up(z, *self.D_down.pyramid(m), t=t)
        return self.D_up(z, self.D_down(m), t=t)

    def forward(self, x: torch.Tensor, m: torch.Tensor, sample: bool | None = None,
                t: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> (y, mu, logvar). z is sampled in training mode (or if ``sample``), else z = mu."""
        mu, logvar = self.encode(x)
        sample = self.training if sample is None else sample
        z = self.sample(mu, logvar) if sample else mu
        return self.decode(z, m, t), mu, logvar

    def grow_latent(self, state: dict, old_c_z: int) -> dict:
        """A state dict of this autoencoder's layout with ``old_c_z`` latent channels, fitted to this
        one's larger C_z: each new mu / logvar output of the encoder starts as a copy of an old one
        (new channel ``k`` copies ``k mod old_c_z``), which the decoder reads with zero weights. The
        grown model decodes what the old one did, and from the first step the new channels carry
        information the decoder can learn to use (the same signal under independent noise), so
        training can make them specialise in what the old ones could not carry. New channels fed
        fresh random weights instead stay at the prior (sigma 1): posterior collapse, measured."""
        c, own = self.cfg.C_z, self.state_dict()
        if old_c_z == c:
            return state
        if old_c_z > c:
            raise ValueError(f"cannot shrink the latent from {old_c_z} to {c} channels")
        state, src = dict(state), torch.arange(c) % old_c_z
        for key in ("E.conv_out.weight", "E.conv_out.bias"):
            mu, logvar = state[key].split(old_c_z)
            state[key] = torch.cat([mu[src], logvar[src]])
        key = "D_up.conv_in.weight"
        state[key] = grow_segments(state[key], torch.zeros_like(own[key]), 1,
                                   (old_c_z, self.cfg.C_map), (c, self.cfg.C_map))
        return state

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
