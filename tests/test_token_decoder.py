"""A decoder that reads the tokens: the tokens' raster (sumo_scendiff/tokens/raster.py), the decoder's
token inputs (model/autoencoder.py, C_t) and what it is trained on (train/token_decoder.py)."""
from functools import partial

import numpy as np
import pytest
import torch

from sumo_scendiff.core.geometry import T0, metres_to_pixels
from sumo_scendiff.core.scene import speeds_from_traj
from sumo_scendiff.map.raster import render_agents
from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder, TokenBranch
from sumo_scendiff.model.detection import C_Y
from sumo_scendiff.tokens.encoding import (
    agent_tokens_from_dicts,
    features_from_scene,
    pad_tokens,
)
from sumo_scendiff.tokens.masking import TokenMaskConfig, choose_tokens, partial_tokens
from sumo_scendiff.tokens.raster import C_T, TOKEN_CHANNELS, token_raster
from sumo_scendiff.train.token_decoder import (
    MISLEAD_SCALE,
    MISLEAD_TURN,
    decoder_conditioning,
    mislead,
)

# without tokens, a heading head or a branch unless a test asks for them
TINY = AutoencoderConfig(enc_channels=(4, 8, 8, 8), dec_channels=(16, 16, 16), C_map=4, heading_bins=0, C_t=0,
                         token_branch=0)


def channel(r: torch.Tensor, name: str) -> torch.Tensor:
    return r[TOKEN_CHANNELS.index(name)]


def test_a_token_is_drawn_around_its_position_with_what_it_gives():
    tok, pad = pad_tokens([agent_tokens_from_dicts([{"x": 10.0, "y": -20.0, "speed": 7.0},
                                                    {"speed": 15.0}]), np.zeros((0, 170), np.float32)])
    r = token_raster(tok, pad, res=64)
    assert r.shape == (2, C_T, 64, 64) and not r[1].any()
    col, row = np.floor(metres_to_pixels(np.array([10.0, -20.0]), 100.0, (64, 64)) + 0.5).astype(int)
    occupied = torch.nonzero(channel(r[0], "token")).tolist()
    assert sorted(occupied) == [[row + dr, col + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)]
    # speed 7 m/s lies in the bin [6, 8): its centre, in units of 10 m/s, and its presence bit
    assert torch.allclose(channel(r[0], "speed")[row, col], torch.tensor(0.7))
    assert channel(r[0], "speed_given")[row, col] == 1
    for absent in ("heading_given", "extents_given", "final_speed_given", "heading_to_final_given",
                   "heading_cos", "length", "final_speed"):
        assert not channel(r[0], absent).any(), absent
    # the token without a position is not drawn (the diffusion model still sees it)
    assert channel(r[0], "token").sum() == 9


def test_the_decoder_reads_one_given_speed_in_both_channels():
    """An absent final speed read as 0 m/s made a decoder draw a speed-only token braking from too
    fast; the decoder sees the given one in both channels, the presence bits unchanged
    (``ScenarioAutoencoder.token_raster``, against the plain ``token_raster``)."""
    tok, pad = pad_tokens([agent_tokens_from_dicts([{"x": 0.0, "y": 0.0, "speed": 13.0},
                                                    {"x": 30.0, "y": 0.0, "final_speed": 3.0},
                                                    {"x": -30.0, "y": 0.0, "speed": 9.0, "final_speed": 1.0}])])
    ae = ScenarioAutoencoder(AutoencoderConfig(**{**TINY.__dict__, "C_t": C_T}))
    filled, plain = ae.token_raster(tok, pad)[0], token_raster(tok, pad, ae.out_res)[0]
    cells = [tuple(np.floor(metres_to_pixels(np.array([x, 0.0]), 100.0, (64, 64)) + 0.5).astype(int)[::-1])
             for x in (0.0, 30.0, -30.0)]
    at = (lambda r, name, k: float(channel(r, name)[cells[k]]))
    assert at(filled, "speed", 0) == at(filled, "final_speed", 0) == at(plain, "speed", 0) == pytest.approx(1.3)
    assert at(plain, "final_speed", 0) == 0.0 and at(filled, "final_speed_given", 0) == 0.0
    assert at(filled, "speed", 1) == at(filled, "final_speed", 1) == pytest.approx(0.3)
    assert at(plain, "speed", 1) == 0.0 and at(filled, "speed_given", 1) == 0.0
    # both given: each its own, as before
    assert (at(filled, "speed", 2), at(filled, "final_speed", 2)) == pytest.approx((0.9, 0.1))
    assert torch.equal(filled[TOKEN_CHANNELS.index("speed_given")], plain[TOKEN_CHANNELS.index("speed_given")])


def test_the_decoder_reads_the_exact_values_a_token_was_made_from():
    """Given the dicts the tokens were encoded from (``exact_values``), the raster carries a token's
    exact speed, final speed and turn instead of its bin's centre (7.4 m/s is bin [6, 8)); a feature
    the token does not give stays absent, a set whose length does not match its tokens is ignored,
    and the one-hot tokens themselves are untouched."""
    from sumo_scendiff.tokens.raster import exact_values
    dicts = [{"x": 10.0, "y": -20.0, "speed": 7.4, "heading_to_final": 0.31}, {"x": -10.0, "y": 5.0}]
    tok, pad = pad_tokens([agent_tokens_from_dicts(dicts)])
    before = tok.clone()
    exact = exact_values([dicts], [2])
    assert exact.shape == (1, 2, 3) and torch.isnan(exact[0, 1]).all() and torch.isnan(exact[0, 0, 1])
    r, binned = token_raster(tok, pad, res=64, exact=exact)[0], token_raster(tok, pad, res=64)[0]
    col, row = np.floor(metres_to_pixels(np.array([10.0, -20.0]), 100.0, (64, 64)) + 0.5).astype(int)
    assert float(channel(r, "speed")[row, col]) == pytest.approx(0.74)
    assert float(channel(binned, "speed")[row, col]) == pytest.approx(0.7)
    assert float(channel(r, "heading_to_final")[row, col]) == pytest.approx(0.31 / 0.7)
    assert not channel(r, "final_speed").any() and torch.equal(tok, before)
    assert torch.isnan(exact_values([dicts], [3])).all()


def test_a_token_at_the_window_edge_is_clipped_and_turns_are_signed():
    tok, pad = pad_tokens([agent_tokens_from_dicts([{"x": -49.9, "y": 49.9, "heading": 0.5, "length": 12.0,
                                                     "width": 2.5, "heading_to_final": -0.3}])])
    r = token_raster(tok, pad, res=64)[0]
    assert channel(r, "token").sum() == 4 and channel(r, "token")[0, 0] == 1
    assert torch.allclose(channel(r, "heading_cos")[0, 0], torch.tensor(np.cos(0.5), dtype=torch.float32))
    assert channel(r, "heading_to_final")[0, 0] < 0 and channel(r, "length")[0, 0] > channel(r, "width")[0, 0]


def test_a_token_changes_what_the_decoder_draws_most_near_the_token():
    """A decoder with C_t reads the token raster: a token changes what it decodes, most near the
    token (the group norms spread a little everywhere); a decoder without C_t ignores it."""
    plain = ScenarioAutoencoder(TINY).eval()
    reads = ScenarioAutoencoder(AutoencoderConfig(**{**TINY.__dict__, "C_t": C_T})).eval()
    tok, pad = pad_tokens([agent_tokens_from_dicts([{"x": 30.0, "y": 30.0, "speed": 2.0}])])
    t = token_raster(tok, pad, reads.out_res)
    z, m = torch.randn(1, TINY.C_z, 16, 16), torch.rand(1, TINY.C_m, 128, 128)
    with torch.no_grad():
        assert torch.equal(plain.decode(z, m, t), plain.decode(z, m))   # a decoder without C_t ignores t
        for conv in reads.D_up.tokens.values():
            conv.weight.normal_()
            conv.bias.zero_()
        diff = (reads.decode(z, m, t) - reads.decode(z, m, torch.zeros_like(t))).abs().sum((0, 1))
    assert diff.shape == (64, 64) and diff.max() > 0
    col, row = metres_to_pixels(np.array([30.0, 30.0]), 100.0, (64, 64))
    peak = np.unravel_index(int(diff.argmax()), diff.shape)
    assert abs(peak[0] - row) <= 4 and abs(peak[1] - col) <= 4, (peak, row, col)


def moving_scene(n: int = 6):
    """n vehicles driving east at 10 m/s, one lane apart (scene frame)."""
    t = np.arange(-2, 3, dtype=np.float64)
    traj = np.stack([np.stack([10.0 * t - 20.0, np.full(5, 3.5 * i - 10.0), np.zeros(5)], -1) for i in range(n)])
    boxes = np.stack([traj[:, T0, 0], traj[:, T0, 1], np.zeros(n), np.full(n, 4.5), np.full(n, 1.8)], -1)
    return boxes.astype(np.float32), traj.astype(np.float32), np.ones((n, 5), bool), np.full((n, 5), 10.0, np.float32)


def test_the_token_choice_is_the_one_partial_tokens_encodes():
    boxes, traj, mask, speed = moving_scene()
    feats, pres = features_from_scene(boxes, traj, mask, speed)
    for seed in range(20):
        p_mask, keep, given = choose_tokens(feats, pres, np.random.default_rng(seed))
        tok, _, p2 = partial_tokens(feats, pres, np.random.default_rng(seed))
        assert p2 == p_mask and len(tok) == keep.sum()
        assert all(not (g & ~keep).any() for g in given.values())
        expected = agent_tokens_from_dicts([{f: float(feats[f][i]) for f in feats if given[f][i]}
                                            for i in np.flatnonzero(keep)])
        assert np.array_equal(tok, expected.reshape(tok.shape))


def test_mislead_moves_only_what_a_token_gives():
    """Given speed: the steps before t = 0 scaled about the t = 0 position; final speed: the steps
    after; heading_to_final: the future turned about it (and its yaw); the pose at t = 0, and every
    agent whose token gives none of them, untouched; p = 0 changes nothing."""
    _, traj, _, _ = moving_scene(4)
    given = {"speed": np.array([True, False, False, False]), "final_speed": np.array([False, True, False, False]),
             "heading_to_final": np.array([False, False, True, False])}
    out = mislead(traj, given, np.random.default_rng(0), p=1.0)
    assert np.array_equal(out[:, T0], traj[:, T0]) and np.array_equal(out[3], traj[3])
    k = (out[0, 0, 0] - out[0, T0, 0]) / (traj[0, 0, 0] - traj[0, T0, 0])
    assert MISLEAD_SCALE[0] <= k <= MISLEAD_SCALE[1] and np.array_equal(out[0, T0 + 1:], traj[0, T0 + 1:])
    assert np.allclose(out[0, :T0, :2] - out[0, T0, :2], k * (traj[0, :T0, :2] - traj[0, T0, :2]), atol=1e-4)
    assert np.array_equal(out[1, :T0], traj[1, :T0]) and not np.allclose(out[1, T0 + 1:], traj[1, T0 + 1:])
    a = out[2, -1, 2]
    assert 0 < abs(a) <= MISLEAD_TURN and np.array_equal(out[2, :T0 + 1], traj[2, :T0 + 1])
    d = out[2, -1, :2] - out[2, T0, :2]
    assert np.isclose(np.arctan2(d[1], d[0]), a, atol=1e-5) and np.isclose(np.hypot(*d), 20.0, atol=1e-4)
    assert np.array_equal(mislead(traj, given, np.random.default_rng(0), p=0.0), traj)


def batch_of(boxes, traj, mask, speed):
    return {"boxes": torch.from_numpy(boxes[None]), "traj": torch.from_numpy(traj[None]),
            "traj_mask": torch.from_numpy(mask[None]), "speed": torch.from_numpy(speed[None]),
            "valid": torch.ones(1, len(boxes), dtype=torch.bool), "index": torch.tensor([0]),
            "agents": torch.from_numpy(render_agents(boxes, traj, mask)[None])}


def test_misled_and_counterfactual_examples():
    """Misled: the encoder sees other motion, the token and the loss the recorded one.
    Counterfactual: the encoder sees the recorded motion, the token and the loss the moved one, and
    the token's speed is the moved trajectory's own, exactly (as generation gives a token's values,
    not its 2 m/s bin's centre)."""
    scene = moving_scene()
    batch = batch_of(*scene)
    every = TokenMaskConfig(p_keep_all_tokens=1.0, p_all_features=1.0)
    read = partial(token_raster, res=64)
    x, t, traj, told = decoder_conditioning(batch, 0, 0, 0, every, 1.0, read)
    assert told.shape == batch["valid"].shape and told.all()     # every agent a token giving its speed
    assert not torch.equal(x, batch["agents"]) and torch.equal(traj, batch["traj"])
    assert torch.allclose(channel(t[0], "speed")[channel(t[0], "speed_given") > 0], torch.tensor(1.0))  # 10 m/s
    x, t, traj, _ = decoder_conditioning(batch, 0, 0, 0, every, 1.0, read, p_counterfactual=1.0)
    assert torch.equal(x, batch["agents"]) and not torch.equal(traj, batch["traj"])
    assert torch.equal(traj[:, :, T0], batch["traj"][:, :, T0])
    told = speeds_from_traj(traj[0].numpy(), scene[2])[:, T0]
    col, row = np.floor(metres_to_pixels(scene[0][:, :2].astype(np.float64), 100.0, (64, 64)) + 0.5).astype(int).T
    drawn = channel(t[0], "speed")[row, col].numpy() * 10.0
    assert np.allclose(drawn, np.clip(told, 0, 20.0), atol=1e-3)
    assert (np.abs(told - 10.0) > 1.0).any()


def test_a_batch_without_tokens_skips_the_branch_with_the_full_paths_gradients():
    """In training, a batch whose token raster is empty leaves the token branch out: its output and
    every gradient are those of the branch's full path (whose where() keeps y and passes the branch
    nothing), and each branch weight still gets a (zero) gradient, as DDP wants."""
    torch.manual_seed(0)
    branch = TokenBranch(feat_ch=8, c_t=C_T, ch=8, out_ch=C_Y + 4, mix_scale=1.0).train()
    for p in branch.parameters():        # a branch that corrects: its zero-initialised heads would hide it
        torch.nn.init.normal_(p, std=0.1)
    y0, h0 = torch.randn(2, C_Y + 4, 16, 16), torch.randn(2, 8, 16, 16)
    empty = torch.zeros(2, C_T, 16, 16)
    weight = torch.randn_like(y0)

    def run(forward):
        branch.zero_grad(set_to_none=True)
        y, h = y0.clone().requires_grad_(), h0.clone().requires_grad_()
        out = forward(y, h)
        (out * weight).sum().backward()
        return out.detach(), y.grad, h.grad, [p.grad for p in branch.parameters()]

    skip = run(lambda y, h: branch(y, h, empty))
    full = run(lambda y, h: branch._corrected(y, h, empty, empty[:, :1] > 0))
    assert torch.equal(skip[0], full[0]) and torch.equal(skip[1], full[1])
    assert skip[2] is None and not full[2].any()         # the features get nothing either way
    assert all(g is not None and not g.any() for g in skip[3] + full[3])
