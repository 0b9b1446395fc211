"""The agent tokens as the raster a token-reading decoder sees (sumo_scendiff/tokens/raster.py), and
that decoder (model/autoencoder.py, C_t)."""
import numpy as np
import torch

from sumo_scendiff.core.geometry import metres_to_pixels
from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from sumo_scendiff.tokens.encoding import agent_tokens_from_dicts, pad_tokens
from sumo_scendiff.tokens.raster import C_T, TOKEN_CHANNELS, token_raster

TINY = AutoencoderConfig(enc_channels=(4, 8, 8, 8), dec_channels=(16, 16, 16), C_map=4, C_m=19)


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


def test_a_token_at_the_window_edge_is_clipped_and_turns_are_signed():
    tok, pad = pad_tokens([agent_tokens_from_dicts([{"x": -49.9, "y": 49.9, "heading": 0.5, "length": 12.0,
                                                     "width": 2.5, "heading_to_final": -0.3}])])
    r = token_raster(tok, pad, res=64)[0]
    assert channel(r, "token").sum() == 4 and channel(r, "token")[0, 0] == 1
    assert torch.allclose(channel(r, "heading_cos")[0, 0], torch.tensor(np.cos(0.5), dtype=torch.float32))
    assert channel(r, "heading_to_final")[0, 0] < 0 and channel(r, "length")[0, 0] > channel(r, "width")[0, 0]


def test_the_token_inputs_start_at_zero_and_are_read_once_trained():
    """A decoder with C_t warm-started from one without decodes as it did, with or without tokens;
    once its token inputs are non-zero, a token changes what it decodes, most near the token (the
    group norms spread a little everywhere)."""
    plain = ScenarioAutoencoder(TINY).eval()
    reads = ScenarioAutoencoder(AutoencoderConfig(**{**TINY.__dict__, "C_t": C_T})).eval()
    assert set(plain.state_dict()) < set(reads.state_dict())
    reads.load_state_dict({**reads.state_dict(), **plain.state_dict()})
    tok, pad = pad_tokens([agent_tokens_from_dicts([{"x": 30.0, "y": 30.0, "speed": 2.0}])])
    t = token_raster(tok, pad, reads.out_res)
    z, m = torch.randn(1, TINY.C_z, 16, 16), torch.rand(1, TINY.C_m, 128, 128)
    with torch.no_grad():
        assert torch.equal(plain.decode(z, m), reads.decode(z, m, t))
        assert torch.equal(plain.decode(z, m, t), plain.decode(z, m))   # a decoder without C_t ignores t
        for conv in reads.D_up.tokens.values():
            conv.weight.normal_()
        diff = (reads.decode(z, m, t) - plain.decode(z, m)).abs().sum((0, 1))
    assert diff.shape == (64, 64) and diff.max() > 0
    col, row = metres_to_pixels(np.array([30.0, 30.0]), 100.0, (64, 64))
    peak = np.unravel_index(int(diff.argmax()), diff.shape)
    assert abs(peak[0] - row) <= 4 and abs(peak[1] - col) <= 4, (peak, row, col)
