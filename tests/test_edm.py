"""EDM preconditioning identities, the Karras schedule and the samplers."""
import math

import pytest
import torch

from sumo_scendiff.model.edm import (
    SIGMA_DATA,
    EDMLoss,
    EDMPrecond,
    c_in,
    c_noise,
    c_out,
    c_skip,
    guided,
    initial_noise,
    karras_sigmas,
    loss_weight,
    num_evaluations,
    sample_dpmpp_2m,
    sample_dpmpp_2m_sde,
    sample_euler,
    sample_euler_ancestral,
    sample_heun,
)

SIGMAS = torch.tensor([1e-3, 0.02, 0.1, 0.5, 1.0, 5.0, 20.0, 80.0], dtype=torch.float64)


class ConstNet(torch.nn.Module):
    """A raw network F returning a fixed (arbitrary) output and recording its inputs."""

    def __init__(self, value: float):
        super().__init__()
        self.value = value

    def forward(self, z_in, c_noise_, **cond):
        self.last = (z_in, c_noise_, cond)
        return torch.full_like(z_in, self.value)


def test_weight_times_c_out_squared_is_one():
    torch.testing.assert_close(loss_weight(SIGMAS) * c_out(SIGMAS) ** 2, torch.ones_like(SIGMAS))


def test_coefficients_match_table1():
    s = torch.tensor(0.7, dtype=torch.float64)
    sd = SIGMA_DATA
    assert c_skip(s).item() == pytest.approx(sd**2 / (0.49 + sd**2))
    assert c_out(s).item() == pytest.approx(0.7 * sd / math.sqrt(0.49 + sd**2))
    assert c_in(s).item() == pytest.approx(1 / math.sqrt(0.49 + sd**2))
    assert c_noise(s).item() == pytest.approx(math.log(0.7) / 4)
    # unit-variance input and training target at every sigma
    assert (c_in(SIGMAS) ** 2 * (SIGMAS ** 2 + sd ** 2)).allclose(torch.ones_like(SIGMAS))


@pytest.mark.parametrize("out", [-100.0, 0.0, 3.0, 1e4])
def test_denoiser_is_identity_as_sigma_to_zero(out):
    z = torch.randn(3, 4, 16, 16, dtype=torch.float64)
    d = EDMPrecond(ConstNet(out))(z, 1e-9)
    torch.testing.assert_close(d, z, atol=2e-9 * max(1.0, abs(out)), rtol=0)  # |c_out F| ~ 1e-9 |F|
    assert c_skip(torch.tensor(1e-9)).item() == pytest.approx(1.0)
    assert c_out(torch.tensor(1e-9)).item() == pytest.approx(0.0, abs=1e-8)


def test_precond_passes_scaled_input_noise_and_cond():
    net = ConstNet(0.0)
    z = torch.randn(2, 4, 8, 8)
    sigma = torch.tensor([0.5, 2.0])
    EDMPrecond(net)(z, sigma, m_enc="map")
    z_in, cn, cond = net.last
    torch.testing.assert_close(z_in, z * c_in(sigma)[:, None, None, None])
    torch.testing.assert_close(cn, sigma.log() / 4)
    assert cond == {"m_enc": "map"}


def test_loss_is_one_for_zero_net_and_per_sample():
    """F = 0 -> D = c_skip z; with sigma fixed the expected loss is analytic: lambda * E||...||^2."""
    z0 = torch.randn(4096, 4, 2, 2) * SIGMA_DATA
    g = torch.Generator().manual_seed(0)
    loss = EDMLoss()(EDMPrecond(ConstNet(0.0)), z0, generator=g, sigma=torch.tensor(1.3))
    assert loss.shape == (4096,)
    # E[(c_skip(z0 + s eps) - z0)^2] = (c_skip-1)^2 sd^2 + c_skip^2 s^2 = c_out^2 -> loss = 1
    assert loss.mean().item() == pytest.approx(1.0, rel=0.03)


def test_loss_sigma_distribution():
    g = torch.Generator().manual_seed(1)
    s = EDMLoss().sample_sigma(100_000, generator=g)
    assert s.log().mean().item() == pytest.approx(-0.5, abs=0.02)
    assert s.log().std().item() == pytest.approx(1.0, abs=0.02)


def test_karras_schedule():
    s = karras_sigmas(20)
    assert s.shape == (21,)
    assert s[0].item() == pytest.approx(20.0) and s[-2].item() == pytest.approx(0.02)
    assert s[-1].item() == 0.0
    assert (s[1:] < s[:-1]).all()
    s1 = karras_sigmas(1)
    assert s1.tolist() == pytest.approx([20.0, 0.0])
    with pytest.raises(ValueError):
        karras_sigmas(0)


def _point_denoiser(z_star):
    def d(z, sigma, **cond):  # the exact denoiser when the data is the single point z_star
        return z_star.expand_as(z)
    return d


@pytest.mark.parametrize("sampler", [sample_euler, sample_heun, sample_dpmpp_2m, sample_euler_ancestral,
                                     sample_dpmpp_2m_sde])
def test_samplers_converge_to_single_point(sampler):
    z_star = torch.tensor([1.0, -2.0, 0.5, 3.0]).reshape(1, 4, 1, 1)
    g = torch.Generator().manual_seed(0)
    z_T = initial_noise((8, 4, 1, 1), generator=g)
    out = sampler(_point_denoiser(z_star), z_T, karras_sigmas(10))
    torch.testing.assert_close(out, z_star.expand_as(out), atol=1e-5, rtol=0)


def test_samplers_on_gaussian_data_convergence_order():
    """Data N(mu, sd^2): the exact denoiser is D = mu + sd^2/(sd^2+s^2)(z-mu) and the exact ODE
    solution z(0) = mu + (z_T - mu) sd / sqrt(sd^2 + s_max^2). Euler is 1st, Heun 2nd order."""
    mu, sd = 2.0, 0.5

    def d(z, sigma, **cond):
        s = torch.as_tensor(sigma)
        return mu + sd**2 / (sd**2 + s**2) * (z - mu)

    g = torch.Generator().manual_seed(3)
    z_T = initial_noise((1000, 1), generator=g, dtype=torch.float64)
    exact = mu + (z_T - mu) * sd / math.sqrt(sd**2 + 20.0**2)
    err = {(s.__name__, n): (s(d, z_T, karras_sigmas(n, dtype=torch.float64)) - exact).abs().max().item()
           for s in (sample_euler, sample_heun, sample_dpmpp_2m) for n in (20, 40)}
    assert err["sample_euler", 40] < 0.1 and err["sample_heun", 40] < 0.01
    assert err["sample_dpmpp_2m", 40] < 0.01
    assert 1.6 < err["sample_euler", 20] / err["sample_euler", 40] < 2.5
    assert err["sample_dpmpp_2m", 20] / err["sample_dpmpp_2m", 40] > 3.5
    assert err["sample_heun", 20] / err["sample_heun", 40] > 3.5


@pytest.mark.parametrize("sampler", [sample_euler_ancestral, sample_dpmpp_2m_sde])
@pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
def test_stochastic_samplers_draw_the_data_distribution(sampler, eta):
    """Data N(mu, sd^2) with its exact denoiser: the SDE samplers' samples have the data's mean and
    spread at any eta (0 is their ODE), though each path gets fresh noise."""
    mu, sd = 2.0, 0.5

    def d(z, sigma, **cond):
        s = torch.as_tensor(sigma)
        return mu + sd**2 / (sd**2 + s**2) * (z - mu)

    g = torch.Generator().manual_seed(3)
    z_T = mu + initial_noise((20000, 1), generator=g, dtype=torch.float64)   # the marginal at sigma_max
    out = sampler(d, z_T, karras_sigmas(80, dtype=torch.float64), generator=g, eta=eta)
    tol = 0.03 if sampler is sample_euler_ancestral else 0.01        # 1st / 2nd order in the step
    assert abs(out.mean().item() - mu) < tol and abs(out.std().item() - sd) < tol


def test_stochastic_samplers_take_each_examples_noise_from_the_noise_sampler():
    """The fresh noise comes from ``noise_sampler``: an example's result depends on its own draws
    only (the generator draws each window's from its own seed), not on the rest of the batch."""
    def d(z, sigma, **cond):
        return 0.5 * z

    def run(seeds):
        rngs = [torch.Generator().manual_seed(s) for s in seeds]
        z_T = torch.cat([initial_noise((1, 2, 4, 4), generator=r) for r in rngs])

        def noise(sigma, sigma_next):
            return torch.cat([torch.randn((1, 2, 4, 4), generator=r) for r in rngs])
        return sample_euler_ancestral(d, z_T, karras_sigmas(6), noise_sampler=noise, eta=1.0)

    a, b = run([1, 2, 3]), run([5, 2])
    torch.testing.assert_close(a[1], b[1], rtol=0, atol=1e-6)
    assert not torch.allclose(a[0], b[0])


def test_determinism_and_cond_forwarding():
    calls = []

    def d(z, sigma, *, tag):
        calls.append(tag)
        return 0.5 * z

    def run(seed):
        g = torch.Generator().manual_seed(seed)
        return sample_euler(d, initial_noise((2, 4, 16, 16), generator=g), karras_sigmas(5),
                            cond={"tag": "c"})

    a, b, c = run(7), run(7), run(8)
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert calls == ["c"] * 15


def test_num_evaluations():
    s = karras_sigmas(20)
    n = {"euler": 0, "heun": 0}

    def counter(key):
        def d(z, sigma, **cond):
            n[key] += 1
            return z
        return d

    sample_euler(counter("euler"), torch.zeros(1, 1), s)
    sample_heun(counter("heun"), torch.zeros(1, 1), s)
    assert n == {"euler": num_evaluations(sample_euler, s), "heun": num_evaluations(sample_heun, s)}
    assert n == {"euler": 20, "heun": 39}


def test_guidance_interpolates_between_the_two_conditions_in_one_batch():
    calls = []

    def d(z, sigma, *, c):
        calls.append(len(z))
        return z * c[:, None]   # D(z | c) = c z, per example

    z = torch.randn(3, 4)
    cond, uncond = {"c": torch.tensor([1.0, 2.0, 3.0])}, {"c": torch.tensor([0.5, 0.5, 0.5])}
    for w in (0.0, 1.0, 3.0):
        expected = z * (0.5 + w * (cond["c"] - 0.5))[:, None]
        assert torch.allclose(guided(d, cond, uncond, w)(z, 1.0), expected)
    assert calls == [6, 3, 6]  # both branches in a single batch of 2B; w = 1 needs no second one
    out = sample_euler(guided(d, cond, uncond, 1.0), z, karras_sigmas(4))  # any sampler takes it
    assert torch.allclose(out, sample_euler(d, z, karras_sigmas(4), cond=cond))


def test_guidance_stops_below_each_examples_sigma_lo_and_only_guided_rows_pay_a_second_pass():
    calls = []

    def d(z, sigma, *, c):
        calls.append((len(z), sigma.tolist()))
        return z * c[:, None]

    z = torch.randn(3, 4)
    cond, uncond = {"c": torch.tensor([1.0, 2.0, 3.0])}, {"c": torch.tensor([0.5, 0.5, 0.5])}
    w, sigma_lo = torch.tensor([3.0, 3.0, 1.0]), torch.tensor([0.0, 1.0, 0.0])
    D = guided(d, cond, uncond, w, sigma_lo)
    guided_c = 0.5 + 3.0 * (cond["c"] - 0.5)
    # sigma 2: rows 0 and 1 guided, row 2 has w = 1 (its null branch is not run)
    assert torch.allclose(D(z, 2.0), z * torch.tensor([guided_c[0], guided_c[1], 3.0])[:, None])
    assert calls[-1][0] == 5
    # sigma 0.5: row 1 is below its sigma_lo, so it gets the conditional denoiser
    assert torch.allclose(D(z, 0.5), z * torch.tensor([guided_c[0], 2.0, 3.0])[:, None])
    assert calls[-1][0] == 4
    # no row guided: one plain pass
    assert torch.allclose(guided(d, cond, uncond, 3.0, 5.0)(z, 1.0), z * cond["c"][:, None])
    assert calls[-1] == (3, [1.0, 1.0, 1.0])


def test_projected_guidance_drops_the_update_along_the_conditional_estimate_per_example():
    def d(z, sigma, *, c):
        return z * c[:, None]

    z = torch.tensor([[1.0, 2.0], [3.0, -1.0]])
    cond, uncond = {"c": torch.tensor([2.0, 2.0])}, {"c": torch.tensor([0.5, 0.5])}
    # D(cond) = 2 z, D(uncond) = 0.5 z: the whole update is along D(cond), so APG leaves D(cond)
    assert torch.allclose(guided(d, cond, uncond, 3.0, 0.0, 0.0)(z, 1.0), 2.0 * z)
    assert torch.allclose(guided(d, cond, uncond, 3.0, 0.0, 1.0)(z, 1.0), guided(d, cond, uncond, 3.0)(z, 1.0))

    def d2(z, sigma, *, c):   # the condition adds a fixed vector: an update with both parts
        return z + c

    cond, uncond = {"c": torch.tensor([[0.0, 1.0], [1.0, 0.0]])}, {"c": torch.zeros(2, 2)}
    out = guided(d2, cond, uncond, 3.0, 0.0, torch.tensor([0.0, 1.0]))(z, 1.0)
    d_c, update = z + cond["c"], cond["c"]
    along = (update * d_c).sum(1, keepdim=True) / (d_c * d_c).sum(1, keepdim=True) * d_c
    assert torch.allclose(out[0], d_c[0] + 2.0 * (update[0] - along[0]))   # projected
    assert torch.allclose(out[1], d_c[1] + 2.0 * update[1])                # plain
    assert abs(float(((out[0] - d_c[0]) * d_c[0]).sum())) < 1e-5           # nothing added along D(cond)


def test_guidance_region_weighs_the_update_per_cell():
    def d(z, sigma, *, c):
        return z + c

    z = torch.zeros(1, 1, 2, 2)
    cond, uncond = {"c": torch.ones(1, 1, 2, 2)}, {"c": torch.zeros(1, 1, 2, 2)}
    region = torch.tensor([[[[1.0, 0.0], [0.0, 1.0]]]])
    out = guided(d, cond, uncond, 3.0, 0.0, 1.0, region)(z, 1.0)
    assert torch.equal(out, torch.tensor([[[[3.0, 1.0], [1.0, 3.0]]]]))   # guided in the region only
    assert torch.equal(guided(d, cond, uncond, 3.0, 0.0, 1.0, torch.ones(1, 1, 2, 2))(z, 1.0),
                       guided(d, cond, uncond, 3.0)(z, 1.0))


def test_condition_guided_weighs_one_entry_and_composes_under_guided():
    from sumo_scendiff.model.edm import condition_guided

    def d(z, sigma, *, a, b):
        return z * a[:, None] + b[:, None]

    z = torch.randn(2, 3)
    a, a_null, b = torch.tensor([2.0, 1.0]), torch.tensor([1.0, 1.0]), torch.tensor([0.5, 0.0])
    D = condition_guided(d, "a", 3.0)
    # D(a) + 2 (D(a) - D(a_null)): only the entry named moves, b is the same in both branches
    assert torch.allclose(D(z, 1.0, a=a, a_null=a_null, b=b), d(z, 1.0, a=a, b=b) + 2.0 * z * (a - a_null)[:, None])
    # a row whose entry equals its null is the plain denoiser
    assert torch.allclose(D(z, 1.0, a=a, a_null=a_null, b=b)[1], d(z, 1.0, a=a, b=b)[1])
    # under guided: both of its branches are guided in the entry, the nested formula
    cond, uncond = {"a": a, "a_null": a_null, "b": b}, {"a": a, "a_null": a_null, "b": torch.zeros(2)}
    D2 = guided(D, cond, uncond, 2.0)(z, 1.0)
    g = lambda c: D(z, 1.0, **dict(c))   # noqa: E731
    assert torch.allclose(D2, g(cond) + (g(cond) - g(uncond)))
