"""Tests of the scenario autoencoder (sumo_scendiff/model/autoencoder.py) and the shared blocks."""
import math

import cv2
import numpy as np
import pytest
import torch

from sumo_scendiff.core.geometry import box_corners, metres_to_pixels
from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from sumo_scendiff.model.blocks import Downsample, ResnetBlock, Upsample
from sumo_scendiff.model.detection import C_Y, DetectionLossConfig, decode_boxes, threshold_boxes

# the paper's VAE, D(z, m) and loss (appendix C): KL weight 0.1 and sampled latents, no heading
# head, no tokens (the tests that need them say so), no speed term, a turn weighted 4 (with the
# shipped settings the overfit test's 300 steps do not settle a straight vehicle's trajectory)
PAPER_LOSS = DetectionLossConfig(box_weight=1.0, vertex_weight=1.0, category_weights=(0.1, 0.3, 4.0),
                                 heading_bin_weight=1.0, speed_weight=0.0, told_speed_weight=0.0)
TINY = AutoencoderConfig(enc_channels=(4, 8, 8, 8), dec_channels=(16, 16, 16), C_map=4, heading_bins=0, C_t=0,
                         kl_weight=0.1, latent_noise=1.0,
                         loss=PAPER_LOSS)


def rasterise(boxes: np.ndarray, traj: np.ndarray, size: float = 100.0, hw: int = 128) -> np.ndarray:
    """The 15-channel agent raster of appendix A for one scene (boxes (N, 5), traj (N, 5, 3))."""
    x = np.zeros((15, hw, hw), np.float32)
    for box, tr in zip(boxes, traj):
        poly = metres_to_pixels(box_corners(*box), size, (hw, hw))
        mask = np.zeros((hw, hw), np.uint8)
        cv2.fillPoly(mask, [np.round(poly * 16).astype(np.int32)], 1, shift=4)
        inside = mask.astype(bool)
        vals = [1.0, math.cos(box[2]), math.sin(box[2])]
        for i in (0, 1, 3, 4):
            d = tr[i, :2] - box[:2]
            vals += [1.0, np.clip(d[0] / 30 + 0.5, 0, 1), np.clip(d[1] / 30 + 0.5, 0, 1)]
        for ch, v in enumerate(vals):
            x[ch][inside] = v
    return x


def test_blocks_api():
    x = torch.randn(2, 8, 16, 16)
    assert ResnetBlock(8, 12)(x).shape == (2, 12, 16, 16)
    blk = ResnetBlock(8, 8, emb_ch=5, dropout=0.1)
    assert blk(x, torch.randn(2, 5)).shape == (2, 8, 16, 16)
    assert Downsample(8)(x).shape == (2, 8, 8, 8)
    assert Upsample(8)(x).shape == (2, 8, 32, 32)


def test_shapes_default_config():
    cfg = AutoencoderConfig()
    ae = ScenarioAutoencoder(cfg).eval()
    x, m = torch.rand(2, 15, 128, 128), torch.rand(2, cfg.C_m, 128, 128)
    mu, logvar = ae.encode(x)
    assert mu.shape == logvar.shape == (2, cfg.C_z, 16, 16)
    assert ae.D_down(m).shape == (2, cfg.C_map, 16, 16)
    y, mu2, _ = ae(x, m)
    assert y.shape == (2, C_Y + 2 * cfg.heading_bins, 64, 64) and torch.allclose(mu, mu2)
    assert torch.allclose(ae.decode(mu, m), y)  # eval: z = mu


def test_map_skips_join_the_decoder_at_their_resolution():
    """D_down's features at 32 and 64 px are added into D_up's blocks of that size: the output
    depends on them."""
    ae = ScenarioAutoencoder(TINY).eval()
    x, m = torch.rand(1, 15, 128, 128), torch.rand(1, TINY.C_m, 128, 128)
    with torch.no_grad():
        seen = {}
        for k in ae.D_up.skip_at:
            ae.D_up.body[k].register_forward_pre_hook(lambda mod, a, k=k: seen.update({k: a[0].shape}) or None)
        y = ae(x, m)[0]
        assert seen == {3: (1, 16, 32, 32), 5: (1, 16, 64, 64)}
        for conv in ae.D_up.skips.values():
            conv.weight.mul_(2.0)
        assert y.shape == (1, C_Y, 64, 64) and not torch.allclose(y, ae(x, m)[0])
        _, feats = ae.D_down.pyramid(m)
        assert [f.shape[-1] for f in feats] == [128, 64, 32]
        assert torch.equal(ae.D_down.pyramid(m)[0], ae.D_down(m))


def test_a_stride2_stem_keeps_every_shape_downstream():
    """stem "stride2": E and D_down start at 64 px with one stride-2 convolution, without the full
    resolution's ResnetBlock and Downsample; the latent, D_down's output and the pyramid the decoder's
    skips read (32 and 64 px, same widths) keep their shapes, so the decoder is the same."""
    full, cheap = (ScenarioAutoencoder(AutoencoderConfig(**{**TINY.__dict__, "stem": s})).eval()
                   for s in ("full", "stride2"))
    x, m = torch.rand(2, 15, 128, 128), torch.rand(2, TINY.C_m, 128, 128)
    with torch.no_grad():
        for ae in (full, cheap):
            mu, logvar = ae.encode(x)
            assert mu.shape == logvar.shape == (2, TINY.C_z, 16, 16)
            out, feats = ae.D_down.pyramid(m)
            assert out.shape == (2, TINY.C_map, 16, 16) and torch.equal(out, ae.D_down(m))
            assert [tuple(f.shape[1:]) for f in feats[1:]] == [(8, 64, 64), (8, 32, 32)]
            assert ae(x, m)[0].shape == (2, C_Y, 64, 64)
        assert tuple(full.D_down.pyramid(m)[1][0].shape[1:]) == (4, 128, 128)
        assert tuple(cheap.D_down.pyramid(m)[1][0].shape[1:]) == (4, 64, 64)
    # the stem is what changed: the decoder's weights fit either, the encoders' do not
    assert full.D_up.state_dict().keys() == cheap.D_up.state_dict().keys()
    assert full.E.conv_in.stride == (1, 1) and cheap.E.conv_in.stride == (2, 2)
    assert sum(p.numel() for p in cheap.E.parameters()) < sum(p.numel() for p in full.E.parameters())
    with pytest.raises(ValueError, match="stem 'half'"):
        ScenarioAutoencoder(AutoencoderConfig(**{**TINY.__dict__, "stem": "half"}))


def test_a_token_branch_changes_only_the_cells_a_token_covers():
    """token_branch > 0: the head's outputs corrected where the token raster's token channel is set;
    with the branch's weights anything, a raster without tokens (or none) decodes exactly as the
    decoder without the branch, and with one token only its (2 RADIUS + 1)^2 cells change."""
    from sumo_scendiff.tokens.raster import C_T
    cfg = {**TINY.__dict__, "C_t": C_T}
    plain, branched = (ScenarioAutoencoder(AutoencoderConfig(**{**cfg, "token_branch": b})).eval() for b in (0, 8))
    branched.load_state_dict({**branched.state_dict(), **plain.state_dict()})
    with torch.no_grad():
        for p in branched.D_up.branch.parameters():
            p.normal_(std=0.1)
        z, m = torch.randn(2, TINY.C_z, 16, 16), torch.rand(2, TINY.C_m, 128, 128)
        t = torch.zeros(2, C_T, 64, 64)
        assert torch.equal(plain.decode(z, m, t), branched.decode(z, m, t))
        assert torch.equal(plain.decode(z, m, None), branched.decode(z, m, None))
        t[1, :, 30:33, 40:43] = 0.5
        t[1, 0, 30:33, 40:43] = 1.0
        changed = (plain.decode(z, m, t) != branched.decode(z, m, t)).any(1)
        assert changed[1, 30:33, 40:43].all() and changed.sum() == 9


def test_the_branchs_gate_draws_a_tokens_speeds_whatever_the_latent():
    """The branch's gate: each step's dx drawn (1 - g) y + g v toward the step a vehicle at the
    token's speeds drives. Closed (g -> 0) the branch is its correction alone; open (g -> 1) every token cell
    decodes the token's speed now and at +2 s (straight on), whatever the latent and the map."""
    from sumo_scendiff.model.autoencoder import DX_CHANNEL, MIX_GAIN, MIX_GATE_START, MIX_STEPS
    from sumo_scendiff.tokens.encoding import agent_tokens_from_dicts, pad_tokens
    from sumo_scendiff.tokens.raster import C_T, exact_values
    cfg = AutoencoderConfig(**{**TINY.__dict__, "C_t": C_T, "token_branch": 8})
    ae = ScenarioAutoencoder(cfg).eval()
    assert float(torch.sigmoid(MIX_GAIN * ae.D_up.branch.mix.bias[0].detach())) == pytest.approx(1 / (1 + math.exp(-MIX_GATE_START)))
    asked = {"x": 6.0, "y": -2.0, "speed": 7.3, "final_speed": 3.1}
    tok, pad = pad_tokens([agent_tokens_from_dicts([asked])])
    t = ae.token_raster(tok, pad, exact_values([[asked]], [1]))
    plain = ScenarioAutoencoder(cfg).eval()
    plain.D_up.branch._mixed = lambda y, t, g: y        # the same branch without its gate
    with torch.no_grad():
        for p in (ae.D_up.branch.conv_out.weight, ae.D_up.branch.conv_out.bias):
            p.normal_(std=0.05)                        # the branch's own correction: anything
        plain.load_state_dict(ae.state_dict())
        for bias, speeds in ((-50.0, None), (50.0, (7.3, 7.3, 5.2, 3.1))):
            ae.D_up.branch.mix.bias.fill_(bias)
            for seed in (0, 1):
                torch.manual_seed(seed)
                z, m = torch.randn(1, TINY.C_z, 16, 16) * 3, torch.rand(1, TINY.C_m, 128, 128)
                y = ae.decode(z, m, t)
                if speeds is None:                     # closed: the branch as without the gate
                    assert torch.allclose(y, plain.decode(z, m, t), atol=1e-6)
                    continue
                cells = t[0, 0] > 0
                dx = y[0, [DX_CHANNEL[st] for st in MIX_STEPS]][:, cells].T   # m, along the t = 0 heading
                assert int(cells.sum()) == 9 and torch.allclose(dx.abs(), torch.tensor(speeds), atol=1e-4)
                assert (dx[:, :2] < 0).all() and (dx[:, 2:] > 0).all()     # past steps backward


def test_no_map_decoder_ignores_the_map():
    """use_map=False (the paper's no-map ablation, `train autoencoder --no-map`): D(z, m) = D(z, 0)."""
    ae = ScenarioAutoencoder(AutoencoderConfig(**{**TINY.__dict__, "use_map": False})).eval()
    z = torch.randn(2, TINY.C_z, 16, 16)
    with torch.no_grad():
        y = ae.decode(z, torch.rand(2, TINY.C_m, 128, 128))
        assert torch.equal(y, ae.decode(z, torch.zeros(2, TINY.C_m, 128, 128)))
        assert torch.equal(y, ae.decode(z, torch.rand(2, TINY.C_m, 128, 128)))


def test_latent_noise_scales_the_reparameterisation():
    torch.manual_seed(0)
    x, m = torch.rand(1, 15, 128, 128), torch.rand(1, TINY.C_m, 128, 128)
    for noise, same in ((0.0, True), (1.0, False)):
        ae = ScenarioAutoencoder(AutoencoderConfig(**{**TINY.__dict__, "latent_noise": noise}))
        with torch.no_grad():
            train_y = ae.train()(x, m)[0]
            eval_y = ae.eval()(x, m)[0]
        assert torch.allclose(train_y, eval_y) == same


def test_overfit_one_scene():
    """Train a tiny autoencoder on one 2-box scene; after overlap removal ("keep the most probable
    detection near each box") both boxes and their trajectories are recovered."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small convs: 1 thread is faster, and much faster on a busy machine
    torch.manual_seed(0)
    boxes = np.array([[10.0, 5.0, 0.4, 4.6, 1.9], [-15.0, -8.0, -2.0, 5.2, 2.1]], np.float32)
    traj = np.zeros((2, 5, 3), np.float32)
    for j, (speed, turn) in enumerate([(8.0, 0.0), (5.0, 0.25)]):  # straight, turning
        for i, t in enumerate((-2, -1, 0, 1, 2)):
            yaw = boxes[j, 2] + turn * t
            traj[j, i] = [boxes[j, 0] + speed * t * math.cos(yaw), boxes[j, 1] + speed * t * math.sin(yaw), yaw]
    batch = dict(x=torch.from_numpy(rasterise(boxes, traj))[None], m=torch.zeros(1, TINY.C_m, 128, 128),
                 boxes=torch.from_numpy(boxes)[None], traj=torch.from_numpy(traj)[None],
                 traj_mask=torch.ones(1, 2, 5, dtype=torch.bool), valid=torch.ones(1, 2, dtype=torch.bool))
    ae = ScenarioAutoencoder(TINY)
    steps = 300
    opt = torch.optim.Adam(ae.parameters(), lr=3e-3)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 1.0 - s / steps)
    try:
        for _ in range(steps):
            out = ae.loss(batch)
            opt.zero_grad()
            out["total"].backward()
            torch.nn.utils.clip_grad_norm_(ae.parameters(), 1.0)
            opt.step()
            sched.step()
        ae.eval()
        with torch.no_grad():
            y, _, _ = ae(batch["x"], batch["m"])
    finally:
        torch.set_num_threads(threads)
    det = threshold_boxes(decode_boxes(y), 0.5)[0]
    gt = batch["boxes"][0]
    near = (det["boxes"][:, None, :2] - gt[None, :, :2]).norm(dim=-1)  # (n, 2)
    for j in range(2):
        cand = torch.nonzero(near[:, j] < 3.0).squeeze(1)
        assert len(cand) > 0
        best = cand[det["prob"][cand].argmax()]
        dyaw = torch.remainder(det["boxes"][best, 2] - gt[j, 2] + math.pi, 2 * math.pi) - math.pi
        assert near[best, j] < 1.0 and dyaw.abs() < 0.1, (det["boxes"][best], gt[j])
        assert (det["boxes"][best, 3:] - gt[j, 3:]).abs().max() < 1.0
        traj_err = (det["traj"][best, :, :2] - batch["traj"][0, j, :, :2]).norm(dim=-1).max()
        assert traj_err < 3.0, traj_err
