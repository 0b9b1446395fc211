"""Conditional denoising UNet M(z; c, sigma) on the scenario latent (paper sec. 3.2-3.3, appx. D.1).

Input: the noisy latent (already scaled by c_in, see :class:`~.edm.EDMPrecond`) z (B, C_z, 16, 16)
concatenated with the encoded map E_m(m) (B, C_map, 16, 16). Levels at 16, 8, 4 px (the paper's
32/16/8 px at half resolution, for the CPU budget), one ResnetBlock per level. The noise level
enters as c_noise -> log-spaced Fourier features -> MLP -> per-channel bias in every ResnetBlock. Tokens enter
through cross-attention (8 heads) at every level but the top one and in the middle: agent tokens
(170-d) and the global scene token (10-d) are embedded by separate MLPs into ``d_model`` and
concatenated as keys/values; absent agent tokens are masked out, the global token is always
attended so no query ever attends to nothing. Beyond the paper, the global token is also added
to the noise embedding (``global_in_emb``), a cheap global FiLM path for the p_mask control.

Position (beyond the paper): a convolutional UNet is nearly translation-invariant, so a pixel's
cross-attention query cannot tell which token's x/y one-hot is "here". With ``pos_freqs`` > 0,
Fourier features of the pixel's window coordinates (``pixel_fourier``) are concatenated to the
input (CoordConv) and added, through a learned projection, to every cross-attention query (as in
DETR) — what ties an agent token's position to the latent pixel that must hold its box.

Token splat (beyond the paper): with ``splat_ch`` > 0, every agent token that has a position is
also embedded by its own MLP into ``splat_ch`` channels and added into the one latent pixel its
position bin falls in (``tokens.token_cells``); the resulting image is concatenated to the input.
Cross-attention alone must *learn* to route a token to its pixel, which a CPU-sized training
run does not (docs/model.md); the splat hands that routing to the network, and
cross-attention keeps carrying tokens without a position and the set-level context.

Widths: the paper uses 64/128/256 channels. On the project's 2-core CPU that UNet runs at
~350 samples/s (batch 32, 16 x 16), short of the >= 600 forwards/s needed for 20 scenes/s with 20
Euler steps, so the default is 32/80/160 (~830 samples/s, 3.3 M parameters); pass
``channels=(64, 128, 256)`` for the paper's widths. Between levels the decoder projects to the next
level's width with a 1x1 conv at the low resolution *before* the (3x3) Upsample, which halves
the decoder cost compared with upsampling at the wide width.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..tokens.encoding import AGENT_TOKEN_DIM, GLOBAL_TOKEN_DIM, token_cells
from .blocks import Downsample, ResnetBlock, Upsample, group_norm, unused


@dataclass(frozen=True)
class UNetConfig:
    """Denoiser hyper-parameters. ``channels[i]`` is the width at resolution ``res / 2**i``."""

    c_z: int = 4                                  # latent channels
    c_map: int = 64                               # encoded-map channels E_m(m)
    res: int = 16                                 # latent side (pixels)
    channels: tuple[int, ...] = (32, 80, 160)     # 16, 8, 4 px (paper: 64, 128, 256; see note)
    num_res_blocks: int = 1                       # ResnetBlocks per level (encoder and decoder)
    attn_levels: tuple[int, ...] = (1, 2)         # levels with cross-attention (8 and 4 px)
    mid_attn: bool = True                         # middle block: Resnet, cross-attn, Resnet
    heads: int = 8
    d_model: int = 256                            # token embedding width (keys / values)
    agent_dim: int = AGENT_TOKEN_DIM
    global_dim: int = GLOBAL_TOKEN_DIM
    emb_mult: int = 4                             # noise-embedding width = emb_mult * channels[0]
    noise_freq_range: tuple[float, float] = (0.25, 16.0)  # Fourier features of c_noise
    global_in_emb: bool = True
    pos_freqs: int = 4                            # Fourier frequencies of pixel coordinates (0: none)
    splat_ch: int = 16                            # channels of the token splat image (0: none)
    dropout: float = 0.0


def pixel_fourier(res: int, n_freqs: int, device=None) -> Tensor:
    """(4 n_freqs, res, res): cos/sin of pi 2^k u and pi 2^k v, k = -1 .. n_freqs - 2, where u, v in
    (-1, 1) are the pixel centres' column / row coordinates across the window (periods 2 windows
    down to 4 / 2^(n_freqs - 2) of a window: 4 latent pixels at res 16 with the default 4)."""
    c = (torch.arange(res, device=device, dtype=torch.float32) + 0.5) / res * 2 - 1
    f = math.pi * 2.0 ** torch.arange(-1, n_freqs - 1, device=device, dtype=torch.float32)
    a = c[None, :] * f[:, None]                                            # (F, res)
    u = torch.cat([a.cos(), a.sin()])[:, None, :].expand(-1, res, res)    # varies along columns
    v = torch.cat([a.cos(), a.sin()])[:, :, None].expand(-1, res, res)    # varies along rows
    return torch.cat([u, v])


class FourierEmbedding(nn.Module):
    """Fourier features of a scalar: (B,) -> (B, ch) = [cos(2 pi f x), sin(2 pi f x)] with ch / 2
    frequencies f log-spaced over ``freq_range`` (cycles per unit of c_noise = ln(sigma) / 4,
    which spans ~1.7 units for sigma in [0.02, 20]: the lowest frequency's period covers the whole
    range, the highest's a 28 % change of sigma). Deterministic (no random frequencies)."""

    def __init__(self, ch: int, freq_range: tuple[float, float] = (0.25, 16.0)):
        super().__init__()
        lo, hi = (math.log(f) for f in freq_range)
        self.register_buffer("freqs", torch.exp(torch.linspace(lo, hi, ch // 2)), persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        x = x.to(self.freqs.dtype)[:, None] * (2 * math.pi * self.freqs[None])
        return torch.cat([x.cos(), x.sin()], dim=1)


def token_mlp(in_dim: int, d: int) -> nn.Sequential:
    """The per-token-type embedding MLP (paper sec. 3.3 "Processing")."""
    return nn.Sequential(nn.Linear(in_dim, d), nn.SiLU(), nn.Linear(d, d), nn.LayerNorm(d))


class TokenSplat(nn.Module):
    """Agent tokens -> (B, ch, res, res): each positioned token's embedding added at its cell."""

    def __init__(self, agent_dim: int, ch: int, hidden: int = 64):
        super().__init__()
        self.ch = ch
        self.mlp = nn.Sequential(nn.Linear(agent_dim, hidden), nn.SiLU(), nn.Linear(hidden, ch))

    def forward(self, agent_tokens: Tensor, agent_pad_mask: Tensor, res: int) -> Tensor:
        b, t = agent_tokens.shape[:2]
        out = agent_tokens.new_zeros(b, self.ch, res * res)
        if t:
            cell, placed = token_cells(agent_tokens, agent_pad_mask, res)
            e = self.mlp(agent_tokens) * placed[..., None].to(agent_tokens.dtype)   # (B, T, ch)
            out.scatter_add_(2, cell[:, None, :].expand(-1, self.ch, -1), e.transpose(1, 2))
        else:
            out = out + unused(self.mlp)
        return out.reshape(b, self.ch, res, res)


class CrossAttention(nn.Module):
    """Pixels attend to the token set: x + proj(MHA(q = GN(x), k = v = ctx)). Output proj is
    zero-initialised so a freshly built block is the identity."""

    def __init__(self, ch: int, d_model: int, heads: int, pos_freqs: int = 0):
        super().__init__()
        if ch % heads:
            raise ValueError(f"channels {ch} not divisible by {heads} heads")
        self.heads, self.pos_freqs = heads, pos_freqs
        self.norm = group_norm(ch)
        self.q = nn.Linear(ch, ch, bias=False)
        self.q_pos = nn.Linear(4 * pos_freqs, ch, bias=False) if pos_freqs else None
        self.kv = nn.Linear(d_model, 2 * ch, bias=False)
        self.proj = nn.Linear(ch, ch)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)

    def forward(self, x: Tensor, ctx: Tensor, attn_mask: Tensor) -> Tensor:
        """x (B, C, H, W); ctx (B, S, d_model); attn_mask (B, 1, 1, S) bool, True = attend."""
        b, c, h, w = x.shape
        hd = c // self.heads
        q = self.q(self.norm(x).flatten(2).transpose(1, 2))                # (B, HW, C)
        if self.q_pos is not None:  # where each query pixel is (DETR-style positional query)
            pos = pixel_fourier(h, self.pos_freqs, x.device).to(x.dtype).flatten(1).T
            q = q + self.q_pos(pos)[None]
        k, v = self.kv(ctx).chunk(2, dim=-1)                               # (B, S, C) each
        q, k, v = (t.reshape(b, -1, self.heads, hd).transpose(1, 2) for t in (q, k, v))
        o = F.scaled_dot_product_attention(q, k, v, attn_mask=attn_mask)   # (B, heads, HW, hd)
        o = self.proj(o.transpose(1, 2).reshape(b, h * w, c))
        return x + o.transpose(1, 2).reshape(b, c, h, w)


class Level(nn.Module):
    """ResnetBlock followed, if ``attn``, by cross-attention over the tokens."""

    def __init__(self, cin: int, cout: int, emb_ch: int, cfg: UNetConfig, attn: bool):
        super().__init__()
        self.res = ResnetBlock(cin, cout, emb_ch, cfg.dropout)
        self.attn = CrossAttention(cout, cfg.d_model, cfg.heads, cfg.pos_freqs) if attn else None

    def forward(self, x: Tensor, emb: Tensor, ctx: Tensor, mask: Tensor) -> Tensor:
        x = self.res(x, emb)
        return self.attn(x, ctx, mask) if self.attn is not None else x


class UNet(nn.Module):
    """Raw network F of the EDM denoiser: forward(z_in, c_noise, m_enc, agent_tokens,
    agent_pad_mask, global_token) -> (B, C_z, res, res)."""

    def __init__(self, cfg: UNetConfig = UNetConfig()):
        super().__init__()
        self.cfg = cfg
        ch = cfg.channels
        emb_ch = cfg.emb_mult * ch[0]
        self.noise_fourier = FourierEmbedding(ch[0], cfg.noise_freq_range)
        self.noise_mlp = nn.Sequential(nn.Linear(ch[0], emb_ch), nn.SiLU(), nn.Linear(emb_ch, emb_ch))
        self.global_emb = nn.Linear(cfg.global_dim, emb_ch) if cfg.global_in_emb else None
        self.agent_mlp = token_mlp(cfg.agent_dim, cfg.d_model)
        self.global_mlp = token_mlp(cfg.global_dim, cfg.d_model)

        self.splat = TokenSplat(cfg.agent_dim, cfg.splat_ch) if cfg.splat_ch else None
        self.conv_in = nn.Conv2d(cfg.c_z + cfg.c_map + 4 * cfg.pos_freqs + cfg.splat_ch, ch[0], 3,
                                 padding=1)
        self.down = nn.ModuleList()
        self.downsample = nn.ModuleList()
        skips, c = [], ch[0]
        for i, co in enumerate(ch):
            for _ in range(cfg.num_res_blocks):
                self.down.append(Level(c, co, emb_ch, cfg, i in cfg.attn_levels))
                c = co
                skips.append(c)
            if i < len(ch) - 1:
                self.downsample.append(Downsample(c))
        self.mid = nn.ModuleList([Level(c, c, emb_ch, cfg, cfg.mid_attn)] +
                                 ([Level(c, c, emb_ch, cfg, False)] if cfg.mid_attn else []))
        self.up = nn.ModuleList()
        self.upsample = nn.ModuleList()
        for i, co in reversed(list(enumerate(ch))):
            for _ in range(cfg.num_res_blocks):
                self.up.append(Level(c + skips.pop(), co, emb_ch, cfg, i in cfg.attn_levels))
                c = co
            if i > 0:  # project to the next level's width at low resolution, then upsample
                proj = nn.Conv2d(c, ch[i - 1], 1) if c != ch[i - 1] else nn.Identity()
                self.upsample.append(nn.Sequential(proj, Upsample(ch[i - 1])))
                c = ch[i - 1]
        self.norm_out = group_norm(c)
        self.conv_out = nn.Conv2d(c, cfg.c_z, 3, padding=1)
        nn.init.zeros_(self.conv_out.weight)
        nn.init.zeros_(self.conv_out.bias)

    def context(self, agent_tokens: Tensor, agent_pad_mask: Tensor, global_token: Tensor
                ) -> tuple[Tensor, Tensor]:
        """Keys/values (B, 1 + T, d_model) = [global; agents] and the attention mask
        (B, 1, 1, 1 + T), True = attend (the global token always)."""
        g = self.global_mlp(global_token)[:, None]                         # (B, 1, d)
        if agent_tokens.shape[1]:
            ctx = torch.cat([g, self.agent_mlp(agent_tokens)], dim=1)
            keep = torch.cat([torch.ones_like(agent_pad_mask[:, :1]), ~agent_pad_mask], dim=1)
        else:
            ctx = g + unused(self.agent_mlp)
            keep = torch.ones(g.shape[0], 1, dtype=torch.bool, device=g.device)
        return ctx, keep[:, None, None, :]

    def forward(self, z_in: Tensor, c_noise: Tensor, m_enc: Tensor, agent_tokens: Tensor,
                agent_pad_mask: Tensor, global_token: Tensor) -> Tensor:
        """z_in (B, C_z, R, R) = c_in * z; c_noise (B,); m_enc (B, C_map, R, R);
        agent_tokens (B, T, 170) (T may be 0); agent_pad_mask (B, T) bool, True = padding;
        global_token (B, 10). Returns F (B, C_z, R, R)."""
        cfg = self.cfg
        emb = self.noise_mlp(self.noise_fourier(c_noise.reshape(-1)))
        if self.global_emb is not None:
            emb = emb + self.global_emb(global_token)
        ctx, mask = self.context(agent_tokens, agent_pad_mask.bool(), global_token)

        inputs = [z_in, m_enc.to(z_in.dtype)]
        if cfg.pos_freqs:
            pos = pixel_fourier(z_in.shape[-1], cfg.pos_freqs, z_in.device).to(z_in.dtype)
            inputs.append(pos[None].expand(z_in.shape[0], -1, -1, -1))
        if self.splat is not None:
            inputs.append(self.splat(agent_tokens, agent_pad_mask.bool(), z_in.shape[-1]).to(z_in.dtype))
        h = self.conv_in(torch.cat(inputs, dim=1))
        hs, k = [], 0
        for i in range(len(cfg.channels)):
            for _ in range(cfg.num_res_blocks):
                h = self.down[k](h, emb, ctx, mask)
                hs.append(h)
                k += 1
            if i < len(cfg.channels) - 1:
                h = self.downsample[i](h)
        for blk in self.mid:
            h = blk(h, emb, ctx, mask)
        k = 0
        for j in range(len(cfg.channels)):
            for _ in range(cfg.num_res_blocks):
                h = self.up[k](torch.cat([h, hs.pop()], dim=1), emb, ctx, mask)
                k += 1
            if j < len(cfg.channels) - 1:
                h = self.upsample[j](h)
        return self.conv_out(F.silu(self.norm_out(h)))


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


@torch.no_grad()
def measure_throughput(net: UNet, batch: int = 32, n_tokens: int = 16, iters: int = 10,
                       train: bool = False) -> float:
    """Samples per second of ``net`` (inference forwards, or full AdamW training steps if
    ``train``) on random inputs; wall clock, so run on a quiet machine (and set
    ``torch.set_num_threads`` first). For benchmarking only."""
    import time

    cfg = net.cfg
    z = torch.randn(batch, cfg.c_z, cfg.res, cfg.res)
    args = (z, torch.randn(batch), torch.randn(batch, cfg.c_map, cfg.res, cfg.res),
            torch.randn(batch, n_tokens, cfg.agent_dim), torch.zeros(batch, n_tokens, dtype=torch.bool),
            torch.zeros(batch, cfg.global_dim))
    opt = torch.optim.AdamW(net.parameters(), 1e-4) if train else None

    def step():
        if not train:
            return net(*args)
        with torch.enable_grad():
            loss = net(*args).pow(2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()

    net.train(train)
    for _ in range(2):
        step()
    t = time.perf_counter()
    for _ in range(iters):
        step()
    return batch * iters / (time.perf_counter() - t)
