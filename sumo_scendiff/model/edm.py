"""EDM diffusion (Karras et al. 2022): preconditioning, training loss, noise schedule and samplers.

Scenario Diffusion (paper sec. 3.2, appendix D.2) trains the latent denoiser with EDM using
sigma_data = 0.5, P_mean = -0.5, P_std = 1, sigma_min = 0.02, sigma_max = 20, rho = 7.

Layout follows NVlabs/edm (``training/networks.py``, ``training/loss.py``) for the preconditioning
and the loss, and k-diffusion for the sampling side: the noise schedule (:func:`karras_sigmas`) is
separate from the solvers, and every solver has the one signature::

    sample_x(denoiser, z_T, sigmas, *, cond=None, generator=None, noise_sampler=None) -> z_0

where ``denoiser(z, sigma, **cond)`` is the preconditioned D(z; sigma, cond) (an :class:`EDMPrecond`
or any function with that signature), ``z_T`` is the initial noise already scaled by ``sigmas[0]``
(see :func:`initial_noise`) and ``sigmas`` is a decreasing 1-D tensor ending in 0. Samplers are
chosen by passing the function, e.g. ``sampler=sample_heun``. The stochastic ones (ancestral, SDE)
draw fresh noise at every step from ``noise_sampler(sigma, sigma_next)`` (k-diffusion's convention:
a standard-normal tensor shaped like z), which lets a caller draw each example's noise from its own
seed; without it from ``generator``. The deterministic solvers ignore both.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import torch
from torch import Tensor, nn

SIGMA_DATA = 0.5
SIGMA_MIN = 0.02
SIGMA_MAX = 20.0
RHO = 7.0
P_MEAN = -0.5
P_STD = 1.0

Denoiser = Callable[..., Tensor]  # D(z, sigma, **cond) -> denoised z, same shape as z
NoiseSampler = Callable[[Tensor, Tensor], Tensor]  # (sigma, sigma_next) -> N(0, I) shaped like z
ETA = 0.5   # the stochastic samplers' share of fresh noise (0: their ODE); chosen in docs/model.md


# --------------------------------------------------------------------------------------------
# Preconditioning (Karras et al. 2022, Table 1, "EDM" column)
# --------------------------------------------------------------------------------------------

def c_skip(sigma: Tensor, sigma_data: float = SIGMA_DATA) -> Tensor:
    """c_skip(sigma) = sigma_data^2 / (sigma^2 + sigma_data^2)."""
    return sigma_data ** 2 / (sigma ** 2 + sigma_data ** 2)


def c_out(sigma: Tensor, sigma_data: float = SIGMA_DATA) -> Tensor:
    """c_out(sigma) = sigma * sigma_data / sqrt(sigma^2 + sigma_data^2)."""
    return sigma * sigma_data / (sigma ** 2 + sigma_data ** 2).sqrt()


def c_in(sigma: Tensor, sigma_data: float = SIGMA_DATA) -> Tensor:
    """c_in(sigma) = 1 / sqrt(sigma^2 + sigma_data^2)."""
    return 1.0 / (sigma ** 2 + sigma_data ** 2).sqrt()


def c_noise(sigma: Tensor) -> Tensor:
    """c_noise(sigma) = ln(sigma) / 4."""
    return sigma.log() / 4.0


def loss_weight(sigma: Tensor, sigma_data: float = SIGMA_DATA) -> Tensor:
    """lambda(sigma) = (sigma^2 + sigma_data^2) / (sigma * sigma_data)^2  (= 1 / c_out(sigma)^2)."""
    return (sigma ** 2 + sigma_data ** 2) / (sigma * sigma_data) ** 2


def _as_batch_sigma(sigma: Tensor | float, z: Tensor) -> Tensor:
    """sigma as a (B,) tensor on z's device/dtype (scalars are broadcast over the batch)."""
    sigma = torch.as_tensor(sigma, dtype=z.dtype, device=z.device)
    if sigma.ndim == 0:
        sigma = sigma.expand(z.shape[0])
    return sigma.reshape(z.shape[0])


class EDMPrecond(nn.Module):
    """Wrap a raw network F(c_in * z, c_noise, **cond) into the denoiser D(z; sigma, cond).

    D(z; sigma) = c_skip(sigma) * z + c_out(sigma) * F(c_in(sigma) * z; c_noise(sigma))
    (paper eq. 2; Karras et al. 2022 eq. 7). ``net`` receives the scaled input, the (B,) noise
    conditioning and every keyword in ``cond`` unchanged (for the UNet: m_enc, agent_tokens,
    agent_pad_mask, global_token).
    """

    def __init__(self, net: nn.Module, sigma_data: float = SIGMA_DATA):
        super().__init__()
        self.net = net
        self.sigma_data = sigma_data

    def forward(self, z: Tensor, sigma: Tensor | float, **cond) -> Tensor:
        s = _as_batch_sigma(sigma, z)
        sb = s.reshape(-1, *([1] * (z.ndim - 1)))
        f = self.net(c_in(sb, self.sigma_data) * z, c_noise(s), **cond)
        return c_skip(sb, self.sigma_data) * z + c_out(sb, self.sigma_data) * f.to(z.dtype)


# --------------------------------------------------------------------------------------------
# Training loss
# --------------------------------------------------------------------------------------------

@dataclass
class EDMLoss:
    """EDM training loss with log(sigma) ~ N(P_mean, P_std^2) (paper eq. 1).

    ``loss(denoiser, z0, cond=..., generator=...)`` returns the per-sample loss, shape (B,):

        lambda(sigma) * mean_over_elements( (D(z0 + sigma * eps; sigma) - z0)^2 )

    which equals the paper's lambda * c_out^2 * ||F(c_in z) - (z0 - c_skip z) / c_out||^2 since
    lambda * c_out^2 = 1. It is a *mean* over latent elements rather than a sum (a constant factor,
    which keeps the loss O(1): it is ~1 for a network that outputs zeros at every sigma).
    """

    p_mean: float = P_MEAN
    p_std: float = P_STD
    sigma_data: float = SIGMA_DATA

    def sample_sigma(self, n: int, *, device=None, dtype=torch.float32,
                     generator: Optional[torch.Generator] = None) -> Tensor:
        """Draw n noise levels with log(sigma) ~ N(p_mean, p_std^2)."""
        rnd = torch.randn(n, device=device, dtype=dtype, generator=generator)
        return (rnd * self.p_std + self.p_mean).exp()

    def __call__(self, denoiser: Denoiser, z0: Tensor, *, cond: Optional[dict] = None,
                 generator: Optional[torch.Generator] = None,
                 sigma: Optional[Tensor] = None, weight: Optional[Tensor] = None) -> Tensor:
        """``weight``: optional per-element weights broadcastable to ``z0`` (e.g. (B, 1, R, R)); the
        squared error is their weighted mean, so each example's loss keeps its scale."""
        b = z0.shape[0]
        if sigma is None:
            sigma = self.sample_sigma(b, device=z0.device, dtype=z0.dtype, generator=generator)
        sigma = _as_batch_sigma(sigma, z0)
        eps = torch.randn(z0.shape, device=z0.device, dtype=z0.dtype, generator=generator)
        sb = sigma.reshape(-1, *([1] * (z0.ndim - 1)))
        d = denoiser(z0 + sb * eps, sigma, **(cond or {}))
        sq = (d - z0).pow(2)
        if weight is None:
            err = sq.flatten(1).mean(1)
        else:
            w = weight.expand_as(sq)
            err = (w * sq).flatten(1).sum(1) / w.flatten(1).sum(1)
        return loss_weight(sigma, self.sigma_data) * err


# --------------------------------------------------------------------------------------------
# Noise schedule (Karras et al. 2022 eq. 5)
# --------------------------------------------------------------------------------------------

def karras_sigmas(n: int, sigma_min: float = SIGMA_MIN, sigma_max: float = SIGMA_MAX,
                  rho: float = RHO, *, device=None, dtype=torch.float32) -> Tensor:
    """The n noise levels sigma_i = (sigma_max^(1/rho) + i/(n-1) (sigma_min^(1/rho) -
    sigma_max^(1/rho)))^rho, i = 0..n-1, followed by sigma_n = 0; shape (n + 1,), decreasing.

    ``n`` is the number of Euler steps (denoiser evaluations); Heun uses 2n - 1 evaluations.
    """
    if n < 1:
        raise ValueError(f"karras_sigmas needs n >= 1 steps, got {n}")
    if n == 1:
        ramp = torch.zeros(1, dtype=torch.float64)
    else:
        ramp = torch.linspace(0, 1, n, dtype=torch.float64)
    lo, hi = sigma_min ** (1 / rho), sigma_max ** (1 / rho)
    sig = (hi + ramp * (lo - hi)) ** rho
    return torch.cat([sig, sig.new_zeros(1)]).to(device=device, dtype=dtype)


def initial_noise(shape: tuple[int, ...], sigma_max: float = SIGMA_MAX, *,
                  generator: Optional[torch.Generator] = None, device=None,
                  dtype=torch.float32) -> Tensor:
    """z_T ~ N(0, sigma_max^2 I): the starting point of every sampler (deterministic given the
    generator's seed)."""
    return torch.randn(shape, generator=generator, device=device, dtype=dtype) * sigma_max


# --------------------------------------------------------------------------------------------
# Samplers of the probability-flow ODE dz/dsigma = (z - D(z; sigma)) / sigma  (paper eq. 3)
# --------------------------------------------------------------------------------------------

@torch.no_grad()
def sample_euler(denoiser: Denoiser, z_T: Tensor, sigmas: Tensor, *, cond: Optional[dict] = None,
                 generator: Optional[torch.Generator] = None, noise_sampler: Optional[NoiseSampler] = None
                 ) -> Tensor:
    """Euler integration of the reverse ODE from sigmas[0] to sigmas[-1] (the paper's sampler).

    One denoiser evaluation per step: len(sigmas) - 1 evaluations. Deterministic; ``generator`` is
    accepted for signature uniformity with stochastic samplers and is unused.
    """
    cond = cond or {}
    z = z_T
    for s_cur, s_next in zip(sigmas[:-1], sigmas[1:]):
        d = (z - denoiser(z, s_cur, **cond)) / s_cur  # dz/dsigma at s_cur
        z = z + (s_next - s_cur) * d
    return z


@torch.no_grad()
def sample_heun(denoiser: Denoiser, z_T: Tensor, sigmas: Tensor, *, cond: Optional[dict] = None,
                generator: Optional[torch.Generator] = None, noise_sampler: Optional[NoiseSampler] = None
                ) -> Tensor:
    """Heun's 2nd-order method, Karras et al. 2022 Algorithm 1 (deterministic, no churn).

    Every step is an Euler predictor plus a trapezoidal corrector, except the last step to
    sigma = 0, which is plain Euler: 2 (len(sigmas) - 1) - 1 evaluations when sigmas ends in 0.
    ``generator`` is unused (signature uniformity).
    """
    cond = cond or {}
    z = z_T
    for s_cur, s_next in zip(sigmas[:-1], sigmas[1:]):
        d = (z - denoiser(z, s_cur, **cond)) / s_cur
        z_next = z + (s_next - s_cur) * d
        if s_next > 0:  # 2nd-order correction
            d_next = (z_next - denoiser(z_next, s_next, **cond)) / s_next
            z_next = z + (s_next - s_cur) * (0.5 * d + 0.5 * d_next)
        z = z_next
    return z


@torch.no_grad()
def sample_dpmpp_2m(denoiser: Denoiser, z_T: Tensor, sigmas: Tensor, *, cond: Optional[dict] = None,
                    generator: Optional[torch.Generator] = None, noise_sampler: Optional[NoiseSampler] = None
                    ) -> Tensor:
    """DPM-Solver++(2M) (Lu et al. 2022, Algorithm 2; as in k-diffusion's ``sample_dpmpp_2m``).

    The ODE in t = -log(sigma) is integrated exactly for a denoised estimate that is linear in t,
    from this step's and the previous step's denoiser outputs: 2nd order at one evaluation per step
    (len(sigmas) - 1 evaluations), so half of Heun's cost for the same order. The first step and the
    last one (to sigma = 0) are 1st order. ``generator`` is unused (signature uniformity).
    """
    cond = cond or {}
    z, d_prev, h_prev = z_T, None, None
    for s_cur, s_next in zip(sigmas[:-1], sigmas[1:]):
        d = denoiser(z, s_cur, **cond)
        if s_next == 0:
            z = d
            break
        h = torch.log(s_cur / s_next)                       # t_next - t, t = -log(sigma)
        if d_prev is not None:
            r = h_prev / h
            d_lin = (1 + 1 / (2 * r)) * d - (1 / (2 * r)) * d_prev
        else:
            d_lin = d
        z = (s_next / s_cur) * z - torch.expm1(-h) * d_lin  # exact step for that estimate
        d_prev, h_prev = d, h
    return z


def _noise_sampler(z: Tensor, generator: Optional[torch.Generator],
                   noise_sampler: Optional[NoiseSampler]) -> NoiseSampler:
    if noise_sampler is not None:
        return noise_sampler
    return lambda sigma, sigma_next: torch.randn(z.shape, generator=generator, device=z.device, dtype=z.dtype)


def ancestral_step(sigma: Tensor, sigma_next: Tensor, eta: float = 1.0) -> tuple[Tensor, Tensor]:
    """(sigma_down, sigma_up): a step from sigma to sigma_next split into a deterministic step down
    to sigma_down and fresh noise of sigma_up, sigma_down^2 + sigma_up^2 = sigma_next^2; eta = 1 is
    DDPM's ancestral sampling, 0 the ODE (k-diffusion's ``get_ancestral_step``)."""
    if not eta:
        return sigma_next, sigma_next * 0.0
    up = torch.minimum(sigma_next, eta * (sigma_next ** 2 * (sigma ** 2 - sigma_next ** 2) / sigma ** 2) ** 0.5)
    return (sigma_next ** 2 - up ** 2) ** 0.5, up


@torch.no_grad()
def sample_euler_ancestral(denoiser: Denoiser, z_T: Tensor, sigmas: Tensor, *, cond: Optional[dict] = None,
                           generator: Optional[torch.Generator] = None,
                           noise_sampler: Optional[NoiseSampler] = None, eta: float = ETA,
                           s_noise: float = 1.0) -> Tensor:
    """Euler steps of the reverse SDE: each step goes down to sigma_down along the ODE and adds
    fresh noise of sigma_up (:func:`ancestral_step`; k-diffusion's ``sample_euler_ancestral``).
    The fresh noise lets every step correct what the denoiser got wrong before instead of
    integrating its errors on (Karras et al. 2022, sec. 4): with an imperfect denoiser the samples
    fall into the data's modes (a queue stands) rather than between them. len(sigmas) - 1
    evaluations."""
    cond = cond or {}
    noise = _noise_sampler(z_T, generator, noise_sampler)
    z = z_T
    for s_cur, s_next in zip(sigmas[:-1], sigmas[1:]):
        denoised = denoiser(z, s_cur, **cond)
        if s_next == 0:
            z = denoised
            break
        down, up = ancestral_step(s_cur, s_next, eta)
        z = z + (z - denoised) / s_cur * (down - s_cur)        # Euler to sigma_down
        z = z + noise(s_cur, s_next) * s_noise * up
    return z


@torch.no_grad()
def sample_dpmpp_2m_sde(denoiser: Denoiser, z_T: Tensor, sigmas: Tensor, *, cond: Optional[dict] = None,
                        generator: Optional[torch.Generator] = None,
                        noise_sampler: Optional[NoiseSampler] = None, eta: float = ETA,
                        s_noise: float = 1.0) -> Tensor:
    """DPM-Solver++(2M) SDE (Lu et al. 2022; k-diffusion's ``sample_dpmpp_2m_sde``, midpoint
    correction): :func:`sample_dpmpp_2m`'s second-order step of the SDE, with fresh noise of
    sigma_next sqrt(1 - e^{-2 eta h}) at every step. len(sigmas) - 1 evaluations."""
    cond = cond or {}
    noise = _noise_sampler(z_T, generator, noise_sampler)
    z, d_prev, h_prev = z_T, None, None
    for s_cur, s_next in zip(sigmas[:-1], sigmas[1:]):
        d = denoiser(z, s_cur, **cond)
        if s_next == 0:
            z = d
            break
        h = torch.log(s_cur / s_next)                       # t_next - t, t = -log(sigma)
        eta_h = eta * h
        z = (s_next / s_cur) * torch.exp(-eta_h) * z - torch.expm1(-h - eta_h) * d
        if d_prev is not None:
            r = h_prev / h
            z = z - 0.5 * torch.expm1(-h - eta_h) * (1 / r) * (d - d_prev)
        if eta:
            z = z + noise(s_cur, s_next) * s_next * (-torch.expm1(-2 * eta_h)).sqrt() * s_noise
        d_prev, h_prev = d, h
    return z


def guided(denoiser: Denoiser, cond: dict, uncond: dict, w: float | Tensor,
           sigma_lo: float | Tensor = 0.0, parallel: float | Tensor = 1.0,
           region: Tensor | None = None) -> Denoiser:
    """Classifier-free guidance (Ho & Salimans 2022, eq. 6 in the denoiser form):
    D_w(z; sigma) = D(z; sigma, cond) + (w - 1) (D(z; sigma, cond) - D(z; sigma, uncond)),
    applied only while sigma > ``sigma_lo`` (guidance in a limited interval, Kynkaanniemi et al.
    2024); below it, D_w = D(z; sigma, cond).

    ``parallel`` < 1 is adaptive projected guidance (APG, Sadat et al. 2025, eqs. 5-7): the update
    dD = D(cond) - D(uncond) is split into its part along D(cond), dD_par = (<dD, D(cond)> /
    |D(cond)|^2) D(cond), and the rest, dD_perp, and D_w = D(cond) + (w - 1) (dD_perp + parallel
    dD_par), the inner products over each example. The parallel part only scales what the
    condition already draws (an exaggerated latent: a vehicle asked to drive 10 m/s decoded at 12);
    the orthogonal part carries what the condition changes. ``parallel`` = 1 is plain guidance.
    ``region`` (B, 1 or C, H, W) in [0, 1] weighs the update per latent cell (and the projection is
    taken over it): guidance where the condition speaks, the conditional denoiser elsewhere.

    w = 1 is the conditional denoiser; w > 1 follows the condition more closely. ``w``,
    ``sigma_lo`` and ``parallel`` are numbers or one value per example (B,). The unconditional
    branch runs, in the same batch as the conditional one, only for the examples guided at that
    sigma. Returns a denoiser taking no condition, for any sampler (``cond=None``).
    """
    def per_example(v: float | Tensor, z: Tensor) -> Tensor:
        return (v.to(z) if isinstance(v, Tensor) else torch.tensor(float(v), dtype=z.dtype,
                                                                   device=z.device)).expand(len(z))

    def D(z: Tensor, sigma: Tensor | float, **_) -> Tensor:
        s = _as_batch_sigma(sigma, z)
        wz = per_example(w, z)
        on = (wz != 1.0) & (s > per_example(sigma_lo, z))
        if not bool(on.any()):
            return denoiser(z, s, **cond)
        both = {k: torch.cat([cond[k], uncond[k][on]]) for k in cond}
        out = denoiser(torch.cat([z, z[on]]), torch.cat([s, s[on]]), **both)
        d, d_u = out[:len(z)], out[len(z):]
        shape = (-1, *[1] * (z.ndim - 1))
        d_c, update = d[on], d[on] - d_u
        d_r = d_c
        if region is not None:
            update, d_r = update * region.to(z)[on], d_c * region.to(z)[on]
        keep = per_example(parallel, z)[on]
        if bool((keep != 1.0).any()):     # the projection only where it is asked for
            dims = tuple(range(1, z.ndim))
            along = (update * d_r).sum(dims, keepdim=True) / (d_r * d_r).sum(dims, keepdim=True).clamp_min(1e-12) * d_r
            update = update - (1.0 - keep.reshape(shape)) * along
        d[on] = d_c + (wz[on] - 1.0).reshape(shape) * update
        return d
    return D


def condition_guided(denoiser: Denoiser, name: str, w: float) -> Denoiser:
    """Classifier-free guidance of one entry of the condition (Ho & Salimans 2022, eq. 6):
    D_w(z; sigma, c) = D(z; sigma, c) + (w - 1) (D(z; sigma, c) - D(z; sigma, c without it)).

    The returned denoiser takes the condition with ``name`` and ``name + "_null"``, that entry's
    value without what is guided (both branches in one batch). It is a denoiser of a condition
    still, so :func:`guided` can wrap it in turn: each part of the condition followed with its own
    weight (Liu et al. 2022), both of :func:`guided`'s branches guided in this entry."""
    def D(z: Tensor, sigma: Tensor | float, **cond) -> Tensor:
        null = cond.pop(name + "_null")
        s = _as_batch_sigma(sigma, z)
        both = {k: torch.cat([v, null if k == name else v]) for k, v in cond.items()}
        out = denoiser(torch.cat([z, z]), torch.cat([s, s]), **both)
        d, d_null = out[:len(z)], out[len(z):]
        return d + (w - 1.0) * (d - d_null)
    return D


def inpainted(denoiser: Denoiser, z_known: Tensor, mask: Tensor) -> Denoiser:
    """Inpainting by replacement in the denoiser form: D'(z; sigma) = mask z_known + (1 - mask)
    D(z; sigma) (the replacement method of Song et al. 2021, sec. 5 / app. I.2, applied to the
    denoised estimate rather than to z). On the masked entries the probability-flow ODE (paper eq. 3) then runs in a
    straight line from the starting noise to ``z_known``, which every sampler reaches at sigma = 0,
    and the rest of z is denoised around them. ``mask`` (B, 1 or C, R, R) in [0, 1] broadcasts over
    ``z_known``; works under :func:`guided` or on its own, with any condition."""
    def D(z: Tensor, sigma: Tensor | float, **cond) -> Tensor:
        return torch.lerp(denoiser(z, sigma, **cond), z_known.to(z), mask.to(z))
    return D


SAMPLERS = {"euler": sample_euler, "heun": sample_heun, "dpmpp-2m": sample_dpmpp_2m,  # CLI names
            "euler-ancestral": sample_euler_ancestral, "dpmpp-2m-sde": sample_dpmpp_2m_sde}
STOCHASTIC = (sample_euler_ancestral, sample_dpmpp_2m_sde)   # draw noise at every step


def num_evaluations(sampler: Callable, sigmas: Tensor) -> int:
    """Denoiser evaluations a built-in sampler makes for a schedule (for throughput budgets)."""
    n = len(sigmas) - 1
    if sampler is sample_heun:
        return 2 * n - int(float(sigmas[-1]) == 0.0)
    return n


__all__ = [
    "SIGMA_DATA", "SIGMA_MIN", "SIGMA_MAX", "RHO", "P_MEAN", "P_STD",
    "c_skip", "c_out", "c_in", "c_noise", "loss_weight", "EDMPrecond", "EDMLoss",
    "karras_sigmas", "initial_noise", "sample_euler", "sample_heun", "sample_dpmpp_2m",
    "sample_euler_ancestral", "sample_dpmpp_2m_sde", "ancestral_step", "NoiseSampler", "ETA",
    "SAMPLERS", "STOCHASTIC", "guided", "condition_guided", "num_evaluations", "inpainted",
]
