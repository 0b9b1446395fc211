"""Conditional UNet: shapes, token conditioning, padding mask, zero tokens, EDM wrapping."""
import pytest
import torch

from sumo_scendiff.model.edm import EDMLoss, EDMPrecond
from sumo_scendiff.model.unet import UNet, UNetConfig, count_parameters
from sumo_scendiff.tokens.encoding import (
    AGENT_TOKEN_DIM,
    GLOBAL_TOKEN_DIM,
    encode_agent_tokens,
    global_token,
    pad_tokens,
    token_cells,
)

CFG = UNetConfig(channels=(16, 32, 64), d_model=32, c_map=8)  # small for fast tests


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Tiny tensors: one thread is faster and robust to a loaded machine (OpenMP oversubscription)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def net():
    torch.manual_seed(0)
    n = UNet(CFG).eval()
    # the output conv and attention projections are zero-initialised (identity / zero output at
    # init); randomise them so that conditioning effects are visible
    with torch.no_grad():
        for name, p in n.named_parameters():
            if "conv_out" in name or ".attn.proj" in name:
                p.normal_(0, 0.2)
    return n


def _inputs(b=2, t=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(b, CFG.c_z, 16, 16, generator=g)
    m = torch.randn(b, CFG.c_map, 16, 16, generator=g)
    tok = torch.rand(b, t, AGENT_TOKEN_DIM, generator=g)
    pad = torch.zeros(b, t, dtype=torch.bool)
    glob = torch.as_tensor(global_token([0.3] * b))
    return z, torch.randn(b, generator=g), m, tok, pad, glob


def test_output_shape_and_zero_init():
    z, cn, m, tok, pad, g = _inputs()
    fresh = UNet(CFG)
    out = fresh(z, cn, m, tok, pad, g)
    assert out.shape == (2, CFG.c_z, 16, 16)
    assert torch.equal(out, torch.zeros_like(out))  # zero-initialised output layer


def test_default_config_shape():
    net = UNet(UNetConfig())
    z, cn, _, tok, pad, g = _inputs(b=1)
    out = net(z, cn, torch.randn(1, 64, 16, 16), tok, pad, g)
    assert out.shape == (1, 4, 16, 16) and count_parameters(net) > 1e6


@torch.no_grad()
def test_tokens_change_output(net):
    z, cn, m, tok, pad, g = _inputs()
    a = net(z, cn, m, tok, pad, g)
    b = net(z, cn, m, tok + 1.0, pad, g)
    c = net(z, cn, m, tok, pad, torch.as_tensor(global_token([0.95, 0.95])))
    assert (a - b).abs().max() > 1e-3 and (a - c).abs().max() > 1e-3
    d = net(z, cn + 0.5, m, tok, pad, g)
    e = net(z, cn, m + 1.0, tok, pad, g)
    assert (a - d).abs().max() > 1e-3 and (a - e).abs().max() > 1e-3


@torch.no_grad()
def test_padded_token_is_ignored(net):
    z, cn, m, tok, pad, g = _inputs()
    a = net(z, cn, m, tok, pad, g)
    junk = torch.randn(2, 2, AGENT_TOKEN_DIM) * 10
    tok2 = torch.cat([tok, junk], 1)
    pad2 = torch.cat([pad, torch.ones(2, 2, dtype=torch.bool)], 1)
    torch.testing.assert_close(net(z, cn, m, tok2, pad2, g), a, atol=1e-5, rtol=1e-5)
    # per-sample: sample 0 has one extra masked token; sample 1 an extra real one
    pad3 = pad2.clone()
    pad3[1, 3] = False
    out = net(z, cn, m, tok2, pad3, g)
    torch.testing.assert_close(out[0], a[0], atol=1e-5, rtol=1e-5)
    assert (out[1] - a[1]).abs().max() > 1e-4


@torch.no_grad()
def test_zero_agent_tokens(net):
    z, cn, m, _, _, g = _inputs()
    empty, pad = pad_tokens([torch.zeros(0, AGENT_TOKEN_DIM)] * 2)
    out = net(z, cn, m, empty, pad, g)
    assert out.shape == (2, CFG.c_z, 16, 16) and torch.isfinite(out).all()
    # all-padded tokens == no tokens
    tok = torch.randn(2, 4, AGENT_TOKEN_DIM)
    torch.testing.assert_close(net(z, cn, m, tok, torch.ones(2, 4, dtype=torch.bool), g), out,
                               atol=1e-5, rtol=1e-5)


def test_a_batch_without_tokens_gives_every_weight_a_gradient():
    """DistributedDataParallel waits for a gradient of every weight on every process: a process
    whose share of a batch holds no agent token must still give the token layers one (zero), and
    the output is the same as without them."""
    torch.manual_seed(0)
    n = UNet(UNetConfig(channels=(16, 32, 64), d_model=32, c_map=8, splat_ch=4))
    z, cn, m, _, _, g = _inputs()
    empty, pad = pad_tokens([torch.zeros(0, AGENT_TOKEN_DIM)] * 2)
    n(z, cn, m, empty, pad, g).pow(2).mean().backward()
    assert all(p.grad is not None for p in n.parameters())
    assert all(float(p.grad.abs().sum()) == 0.0 for p in n.agent_mlp.parameters())
    with torch.no_grad():
        torch.testing.assert_close(n(z, cn, m, empty, pad, g), n.eval()(z, cn, m, empty, pad, g))


def test_edm_training_step_reduces_loss():
    torch.manual_seed(0)
    den = EDMPrecond(UNet(CFG))
    z, _, m, tok, pad, g = _inputs(b=8)
    cond = dict(m_enc=m, agent_tokens=tok, agent_pad_mask=pad, global_token=g)
    opt = torch.optim.AdamW(den.parameters(), 1e-3)
    loss_fn, sigma = EDMLoss(), torch.full((8,), 1.0)
    gen = torch.Generator().manual_seed(0)
    first = loss_fn(den, z * 0.5, cond=cond, sigma=sigma, generator=gen).mean()
    for _ in range(8):
        gen = torch.Generator().manual_seed(0)
        loss = loss_fn(den, z * 0.5, cond=cond, sigma=sigma, generator=gen).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < first.item()
    assert GLOBAL_TOKEN_DIM == 23   # p_mask (10), density (12), density's presence bit


def test_token_cells_follow_the_raster_convention():
    import numpy as np

    from sumo_scendiff.core.geometry import metres_to_pixels
    from sumo_scendiff.tokens.encoding import encode_agent_tokens, token_cells
    xy = np.array([[-49.0, 49.0], [0.1, -0.1], [30.0, 12.0], [-12.6, -37.4], [49.9, -49.9]])
    tok, pad = pad_tokens([encode_agent_tokens({"x": xy[:, 0], "y": xy[:, 1]})])
    cell, placed = token_cells(tok, pad, 16)
    colrow = np.floor(metres_to_pixels(xy, 100.0, (16, 16)) + 0.5).astype(int)
    assert placed.all()
    assert cell[0].tolist() == (colrow[:, 1] * 16 + colrow[:, 0]).tolist()
    # no position, or padding: not placed
    tok2, pad2 = pad_tokens([encode_agent_tokens({"speed": np.array([5.0, 6.0])})[:1]])
    assert not token_cells(tok2, pad2, 16)[1].any()
    assert not token_cells(tok, torch.ones_like(pad), 16)[1].any()


@torch.no_grad()
def test_splat_writes_each_token_at_its_cell_only():
    import numpy as np

    from sumo_scendiff.model.unet import TokenSplat
    from sumo_scendiff.tokens.encoding import encode_agent_tokens
    torch.manual_seed(0)
    splat = TokenSplat(AGENT_TOKEN_DIM, 4)
    tok, pad = pad_tokens([encode_agent_tokens({"x": np.array([30.0, np.nan]),
                                                "y": np.array([12.0, np.nan]),
                                                "speed": np.array([3.0, 9.0])})])
    img = splat(tok, pad, 16)
    nz = img.abs().sum(1)[0].nonzero().tolist()
    assert nz == [[6, 12]]  # row 6 (y = 12 m), column 12 (x = 30 m); the unplaced token adds nothing


def test_no_map_ablation_ignores_the_map_and_survives_its_config_round_trip():
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
    cfg = DiffusionConfig(map_channels=(4, 8, 8, 8), unet=CFG, use_map=False)
    cfg = ckpt.config_from_dict(DiffusionConfig, ckpt.config_to_dict(cfg))  # as a checkpoint stores it
    model = ScenarioDiffusion(cfg).eval()
    g = torch.Generator().manual_seed(0)
    m1, m2 = (torch.rand(1, cfg.C_m, 128, 128, generator=g) for _ in range(2))
    tok, pad = torch.zeros(1, 0, AGENT_TOKEN_DIM), torch.zeros(1, 0, dtype=torch.bool)
    glob = torch.as_tensor(global_token([1.0]))
    z = [model.sample(m, tok, pad, glob, steps=3, noise=torch.ones(1, CFG.c_z, 16, 16)) for m in (m1, m2)]
    assert not cfg.use_map and torch.equal(z[0], z[1])
    model.cfg = DiffusionConfig(map_channels=(4, 8, 8, 8), unet=CFG)  # the same weights, map on
    assert not torch.equal(model.encode_map(m1), model.encode_map(m2))


def test_a_stride2_stem_gives_the_same_map_encoding_shape():
    """DiffusionConfig.stem "stride2": E_m starts at 64 px; its output, what the UNet reads, keeps
    its shape, and the option survives a checkpoint's config round trip."""
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
    cfg = DiffusionConfig(map_channels=(4, 8, 8, 8), unet=CFG, stem="stride2")
    cfg = ckpt.config_from_dict(DiffusionConfig, ckpt.config_to_dict(cfg))
    full, cheap = (ScenarioDiffusion(c) for c in (DiffusionConfig(map_channels=(4, 8, 8, 8), unet=CFG), cfg))
    m = torch.rand(2, cfg.C_m, 128, 128)
    assert cfg.stem == "stride2" and cheap.E_m.conv_in.stride == (2, 2)
    assert cheap.encode_map(m).shape == full.encode_map(m).shape == (2, CFG.c_map, 16, 16)
    assert full.denoiser.state_dict().keys() == cheap.denoiser.state_dict().keys()


def test_training_noise_levels_follow_the_config():
    from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
    from sumo_scendiff.model.edm import P_MEAN, P_STD
    shipped = ScenarioDiffusion(DiffusionConfig(map_channels=(4, 8, 8, 8), unet=CFG)).edm_loss
    assert (shipped.p_mean, shipped.p_std) == (0.3, 1.4) and (P_MEAN, P_STD) == (-0.5, 1.0)  # appendix D's
    paper = ScenarioDiffusion(DiffusionConfig(map_channels=(4, 8, 8, 8), unet=CFG, P_mean=P_MEAN, P_std=P_STD))
    log_sigma = paper.edm_loss.sample_sigma(20_000, generator=torch.Generator().manual_seed(0)).log()
    assert abs(float(log_sigma.mean()) + 0.5) < 0.05 and abs(float(log_sigma.std()) - 1.0) < 0.05


def _small_diffusion():
    """A small diffusion model whose zero-initialised outputs are randomised (conditioning visible),
    two maps, their starting noise and the generator that drew them."""
    from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
    torch.manual_seed(0)
    model = ScenarioDiffusion(DiffusionConfig(map_channels=(4, 8, 8, 8), unet=CFG)).eval()
    with torch.no_grad():
        for name, p in model.named_parameters():
            if "conv_out" in name or ".attn.proj" in name:
                p.normal_(0, 0.2)
    g = torch.Generator().manual_seed(0)
    m = torch.rand(2, model.cfg.C_m, 128, 128, generator=g)
    noise = torch.randn(2, CFG.c_z, 16, 16, generator=g)
    return model, m, noise, g


def test_guidance_follows_the_tokens_and_skips_a_map_only_batch():
    model, m, noise, g = _small_diffusion()
    tok, pad = pad_tokens([torch.rand(2, AGENT_TOKEN_DIM, generator=g), torch.zeros(0, AGENT_TOKEN_DIM)])
    glob = torch.as_tensor(global_token([0.0, 0.3]))

    def run(w, tok=tok, pad=pad, glob=glob):
        return model.sample(m, tok, pad, glob, steps=3, noise=noise, guidance=w)
    assert not torch.allclose(run(1.0), run(3.0))
    assert torch.equal(run(3.0), run(3.0))  # deterministic
    # a map-only batch (no token, p_mask = 1): the two conditions agree and guidance changes nothing
    none, none_pad = pad_tokens([torch.zeros(0, AGENT_TOKEN_DIM)] * 2)
    ones = torch.as_tensor(global_token([1.0, 1.0]))
    assert torch.equal(run(1.0, none, none_pad, ones), run(3.0, none, none_pad, ones))


def test_local_guidance_changes_only_the_windows_with_tokens_and_only_around_them():
    model, m, noise, g = _small_diffusion()
    tok, pad = pad_tokens([encode_agent_tokens({"x": [3.0, -30.0], "y": [0.0, 20.0], "speed": [12.0, 4.0]}),
                           torch.zeros(0, AGENT_TOKEN_DIM)])
    glob = torch.as_tensor(global_token([0.5, 0.3]))

    def run(local):
        return model.sample(m, tok, pad, glob, steps=3, noise=noise, guidance=3.0, scene_guidance=2.0,
                            local=local)
    a, b = run(True), run(False)
    assert not torch.allclose(a[0], b[0])      # the window with tokens: local
    assert torch.allclose(a[1], b[1])          # the one without: the global token's plain guidance
    # its guidance reaches the cells within one of each positioned token, nothing else
    parallel, region = model.local_guidance(model.cond(m, tok, pad, glob))
    assert parallel.tolist() == [0.0, 1.0] and region.shape == (2, 1, CFG.res, CFG.res)
    cell, placed = token_cells(tok, pad, CFG.res)
    want = torch.zeros(CFG.res, CFG.res)
    for c in cell[0][placed[0]].tolist():
        r, k = divmod(c, CFG.res)
        want[max(r - 1, 0):r + 2, max(k - 1, 0):k + 2] = 1.0
    assert torch.equal(region[0, 0], want) and bool(region[1].eq(1.0).all())


def test_a_token_without_a_position_is_guided_over_the_whole_window():
    from sumo_scendiff.tokens.encoding import token_region
    tok, pad = pad_tokens([encode_agent_tokens({"x": [3.0, float("nan")], "y": [0.0, float("nan")],
                                                "speed": [12.0, 4.0]})])
    assert bool(token_region(tok, pad, 16).eq(1.0).all())


def test_signal_guidance_changes_only_the_windows_that_show_a_light():
    from sumo_scendiff.map.raster import MAP_CHANNELS
    model, m, noise, g = _small_diffusion()
    m = m.clone()
    m[1, [MAP_CHANNELS.index("signal_go"), MAP_CHANNELS.index("signal_stop")]] = 0.0   # lights unknown
    tok, pad = pad_tokens([torch.zeros(0, AGENT_TOKEN_DIM)] * 2)
    glob = torch.as_tensor(global_token([1.0, 1.0]))

    def run(w, guidance=1.0):
        return model.sample(m, tok, pad, glob, steps=3, noise=noise, scene_guidance=guidance, signal_guidance=w)
    for guidance in (1.0, 2.0):                  # alone, and under the global token's guidance
        a, b = run(3.0, guidance), run(1.0, guidance)
        assert not torch.allclose(a[0], b[0]) and torch.allclose(a[1], b[1], atol=1e-5)
