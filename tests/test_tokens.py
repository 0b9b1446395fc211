"""Agent / global token encoding, partial tokenisation, validation and padding."""
import numpy as np
import pytest
import torch

from sumo_scendiff.tokens.encoding import (
    AGENT_TOKEN_DIM,
    FEATURE_SLICES,
    FEATURES,
    GLOBAL_TOKEN_DIM,
    PRESENCE_SLICE,
    TokenError,
    agent_tokens_from_dicts,
    encode_agent_tokens,
    features_from_scene,
    global_token,
    pad_tokens,
    tokens_from_scene,
    validate_token_features,
)
from sumo_scendiff.tokens.masking import (
    TokenMaskConfig,
    partial_tokens,
    sample_feature_dropout,
    sample_token_mask,
)


def _bin_of(tokens, name):
    seg = tokens[:, FEATURE_SLICES[name]]
    assert np.allclose(seg.sum(1), 1.0)  # exactly one hot
    return seg.argmax(1).tolist()


def test_dims():
    assert AGENT_TOKEN_DIM == 170 and GLOBAL_TOKEN_DIM == 23
    assert PRESENCE_SLICE == slice(162, 170)
    assert sum(s.stop - s.start for s in FEATURE_SLICES.values()) == 162


def test_position_bins():
    t = encode_agent_tokens({"x": np.array([-50.0, 49.99, 0.0, 50.0, -60.0]),
                             "y": np.array([0.0, -50.0, 1.5625, -1e-6, 60.0])})
    assert _bin_of(t, "x") == [0, 63, 32, 63, 0]
    assert _bin_of(t, "y") == [32, 0, 33, 31, 63]


def test_speed_and_heading_to_final_bins():
    t = encode_agent_tokens({"speed": np.array([19.9, 25.0, 0.0, 2.0, -1.0]),
                             "final_speed": np.array([0.0, 1.99, 10.0, 20.0, 100.0]),
                             "heading_to_final": np.array([-0.7, 0.0, 0.7, -2.0, 0.069])})
    assert _bin_of(t, "speed") == [9, 9, 0, 1, 0]
    assert _bin_of(t, "final_speed") == [0, 0, 5, 9, 9]
    assert _bin_of(t, "heading_to_final") == [0, 5, 9, 0, 5]


def test_continuous_features():
    t = encode_agent_tokens({"heading": np.array([0.0, np.pi / 2]), "length": np.array([4.5, 12.0]),
                             "width": np.array([1.8, 2.5])})
    np.testing.assert_allclose(t[:, FEATURE_SLICES["heading"]], [[1, 0], [0, 1]], atol=1e-7)
    np.testing.assert_allclose(t[:, FEATURE_SLICES["length"]][:, 0], np.log1p([4.5, 12.0]), rtol=1e-6)
    np.testing.assert_allclose(t[:, FEATURE_SLICES["width"]][:, 0], np.log1p([1.8, 2.5]), rtol=1e-6)


def test_presence_bits_and_absent_zeroed():
    feats = {"x": np.array([10.0, 10.0, np.nan]), "y": np.array([5.0, 5.0, np.nan]),
             "speed": np.array([3.0, 3.0, 3.0]), "heading": torch.tensor([0.3, 0.3, 0.3])}
    present = {"speed": np.array([True, False, True])}
    t = encode_agent_tokens(feats, present)
    assert t.shape == (3, 170) and t.dtype == np.float32
    bits = t[:, PRESENCE_SLICE]
    i = {n: k for k, n in enumerate(FEATURES)}
    assert bits[:, i["x"]].tolist() == [1, 1, 0] and bits[:, i["y"]].tolist() == [1, 1, 0]
    assert bits[:, i["speed"]].tolist() == [1, 0, 1] and bits[:, i["heading"]].tolist() == [1, 1, 1]
    for name in ("length", "width", "final_speed", "heading_to_final"):
        assert bits[:, i[name]].sum() == 0 and not t[:, FEATURE_SLICES[name]].any()
    assert not t[1, FEATURE_SLICES["speed"]].any() and not t[2, FEATURE_SLICES["x"]].any()
    assert encode_agent_tokens({}).shape == (0, 170)


def test_unknown_feature_in_encode():
    with pytest.raises(TokenError, match="unknown token feature 'spead'"):
        encode_agent_tokens({"spead": np.zeros(2)})


def _scene():
    # agent 0: moving along +x, turning left; 1: stationary; 2: +2 s unobserved
    boxes = np.array([[0.0, 0.0, 0.0, 4.5, 1.8], [10.0, 10.0, 1.0, 5.0, 2.0], [-20, 30, 3.0, 12, 2.5]])
    traj = np.zeros((3, 5, 3))
    traj[:, :, :2] = boxes[:, None, :2]
    traj[0, 4, :2] = [10.0, 2.0]  # atan2(2, 10) = 0.197 rad -> bin floor((0.197+0.7)/0.14) = 6
    traj[1, 4, :2] = [10.2, 10.1]  # 0.22 m: undefined direction
    mask = np.ones((3, 5), bool)
    mask[2, 3:] = False
    speed = np.array([[5, 5, 6, 7, 8.5], [0, 0, 0, 0, 0.1], [3, 3, 3, 0, 0]], float)
    return boxes, traj, mask, speed


def test_tokens_from_scene():
    feats, pres = features_from_scene(*_scene())
    assert feats["heading_to_final"][0] == pytest.approx(np.arctan2(2, 10))
    assert pres["heading_to_final"].tolist() == [True, False, False]
    assert pres["final_speed"].tolist() == [True, True, False]
    t = tokens_from_scene(*_scene())
    assert t.shape == (3, 170)
    assert _bin_of(t[:1], "heading_to_final") == [6]
    assert _bin_of(t, "speed") == [3, 0, 1]
    assert _bin_of(t[:2], "final_speed") == [4, 0]
    assert t[:, PRESENCE_SLICE].sum(1).tolist() == [8, 7, 6]
    assert tokens_from_scene(np.zeros((0, 5)), np.zeros((0, 5, 3)), np.zeros((0, 5), bool),
                             np.zeros((0, 5))).shape == (0, 170)


@pytest.mark.parametrize("p,bucket", [(0.0, 0), (0.05, 0), (0.1, 1), (0.3, 3), (0.7, 7), (0.95, 9),
                                      (1.0, 9)])
def test_global_token_buckets(p, bucket):
    g = global_token(p, dim=10)                    # a model without the density condition
    assert g.shape == (10,) and g.sum() == 1 and g.argmax() == bucket
    g = global_token(p)                            # density absent: its bins and presence bit zero
    assert g.shape == (23,) and g.sum() == 1 and g.argmax() == bucket


@pytest.mark.parametrize("density,bucket", [(0.5, 0), (2.0, 0), (2.9, 1), (20.0, 6), (149.0, 11), (900.0, 11)])
def test_density_bins_are_log_spaced_and_clipped(density, bucket):
    from sumo_scendiff.tokens.encoding import DENSITY_BINS, density_of_bin
    g = global_token(0.5, density=density)
    assert g[10:10 + DENSITY_BINS].argmax() == bucket and g[10 + DENSITY_BINS] == 1 and g.sum() == 3
    assert 2.0 <= density_of_bin(bucket) <= 150.0


def test_density_absent_present_and_refused():
    g = global_token([0.2, 0.2, 0.2], density=[np.nan, 10.0, np.nan])
    assert g[:, -1].tolist() == [0.0, 1.0, 0.0]
    with pytest.raises(TokenError, match="density"):
        global_token(0.2, density=-3.0)
    with pytest.raises(TokenError, match="no density condition"):
        global_token(0.2, density=10.0, dim=10)


def test_global_token_batched_and_invalid():
    assert global_token([0.0, 1.0]).argmax(1).tolist() == [0, 9]
    with pytest.raises(TokenError):
        global_token(1.2)


def test_sample_token_mask_statistics():
    rng = np.random.default_rng(0)
    draws = [sample_token_mask(20, rng) for _ in range(6000)]
    p = np.array([d[0] for d in draws])
    assert (p == 0).mean() == pytest.approx(0.4, abs=0.03)
    assert p[p > 0].mean() == pytest.approx(2 / 3, abs=0.02)
    keep = np.stack([d[1] for d in draws])
    assert keep[p == 0].all()
    assert (1 - keep.mean(1))[p > 0].mean() == pytest.approx(2 / 3, abs=0.02)


def test_map_only_share_of_the_token_mask():
    cfg = TokenMaskConfig(p_keep_all_tokens=0.3, p_map_only=0.25)
    rng = np.random.default_rng(0)
    draws = [sample_token_mask(5, rng, cfg) for _ in range(8000)]
    p = np.array([d[0] for d in draws])
    assert (p == 0).mean() == pytest.approx(0.3, abs=0.02) and (p == 1).mean() == pytest.approx(0.25, abs=0.02)
    assert not np.stack([d[1] for d in draws])[p == 1].any()  # the map alone: no token kept


def test_feature_dropout_statistics():
    cfg = TokenMaskConfig()
    keep = sample_feature_dropout(200_000, np.random.default_rng(1), cfg)
    assert (keep["x"] == keep["y"]).all() and (keep["length"] == keep["width"]).all()
    assert 1 - keep["speed"].mean() == pytest.approx(0.5 * 0.3, abs=0.005)
    assert 1 - keep["x"].mean() == pytest.approx(0.5 * 0.15, abs=0.005)
    allkept = np.stack([keep[n] for n in FEATURES]).all(0).mean()
    assert allkept == pytest.approx(0.5 + 0.5 * 0.85 * 0.7**5, abs=0.005)


def test_partial_tokens():
    feats, pres = features_from_scene(*_scene())
    rng = np.random.default_rng(2)
    for _ in range(50):
        tok, g, p = partial_tokens(feats, pres, rng)
        assert tok.shape[1] == 170 and tok.shape[0] <= 3 and g.argmax() == min(int(p * 10), 9)
        # never resurrects a feature absent in the scene (h2f: 1 agent, final_speed: 2 agents)
        bits = tok[:, PRESENCE_SLICE]
        assert bits[:, FEATURES.index("heading_to_final")].sum() <= 1
        assert bits[:, FEATURES.index("final_speed")].sum() <= 2
        assert (bits[:, 0] == bits[:, 1]).all()  # x and y dropped together


@pytest.mark.parametrize("feats,msg", [
    ({"speeed": 3.0}, "unknown token feature 'speeed'"),
    ({"speed": -1.0}, "'speed' must be >= 0"),
    ({"final_speed": [1.0, -0.5]}, "'final_speed' must be >= 0"),
    ({"length": -4.0, "width": 2.0}, "'length' must be > 0"),
    ({"length": 4.0, "width": 0.0}, "'width' must be > 0"),
    ({"x": 51.0, "y": 0.0}, "outside the 100 m window"),
    ({"x": [0.0, 0.0], "y": [-10.0, -50.5]}, "outside the 100 m window"),
    ({"speed": "fast"}, "'speed' must be numeric"),
    ({"heading": [0.1, "a"]}, "must be numeric"),
    ({"length": True, "width": 2.0}, "must be numeric"),
    ({"heading": float("inf")}, "must be finite"),
    ({"heading": [[0.0, 1.0]]}, "1-D sequence"),
    ({"x": 1.0}, "x and y .* must be given together"),
    ({"length": [4.0, 5.0], "width": [2.0, None]}, "length and width"),
    ({"speed": [1.0, 2.0], "heading": [0.0]}, "different lengths"),
])
def test_validation_errors(feats, msg):
    with pytest.raises(TokenError, match=msg) as e:
        validate_token_features(feats)
    assert isinstance(e.value, ValueError) and "\n" not in str(e.value)


def test_validation_ok_and_dict_api():
    v = validate_token_features({"x": 50.0, "y": -50.0, "speed": [0.0], "heading": None})
    assert set(v) == {"x", "y", "speed"} and v["x"].tolist() == [50.0]
    t = agent_tokens_from_dicts([{"x": 10, "y": -3.5, "heading": 0.0, "speed": 8},
                                 {"length": 12.0, "width": 2.5}])
    bits = t[:, PRESENCE_SLICE]
    assert bits[0].tolist() == [1, 1, 1, 0, 0, 1, 0, 0] and bits[1].tolist() == [0, 0, 0, 1, 1, 0, 0, 0]
    assert agent_tokens_from_dicts([]).shape == (0, 170)
    with pytest.raises(TokenError, match="agent token 1: .*'speed' must be >= 0"):
        agent_tokens_from_dicts([{"speed": 1}, {"speed": -1}])


def test_pad_tokens():
    toks, pad = pad_tokens([np.ones((2, 170)), np.zeros((0, 170)), torch.ones(3, 170)])
    assert toks.shape == (3, 3, 170) and toks.dtype == torch.float32
    assert pad.tolist() == [[False, False, True], [True, True, True], [False, False, False]]
    assert toks[0, 2].abs().sum() == 0
    toks, pad = pad_tokens([np.zeros((0, 170))] * 4)
    assert toks.shape == (4, 0, 170) and pad.shape == (4, 0)


@pytest.mark.parametrize("agents, message", [
    ([{"speed": [3.0]}], "must be a scalar"),
    ([{"heading_to_final": 40.0}], "radians"),
    ([{"heading": -90}], "radians"),
])
def test_user_token_shapes_and_units(agents, message):
    from sumo_scendiff.tokens.encoding import TokenError, agent_tokens_from_dicts
    with pytest.raises(TokenError, match=message):
        agent_tokens_from_dicts(agents)


@pytest.mark.parametrize("bad", [True, "a lot", None, 1.5, -0.1])
def test_global_token_rejects_non_numbers(bad):
    from sumo_scendiff.tokens.encoding import TokenError, global_token
    with pytest.raises(TokenError, match="p_mask"):
        global_token(bad)


def test_token_cells_weigh_the_latent_cells_under_positioned_tokens():
    import torch

    from sumo_scendiff.model.edm import EDMLoss
    from sumo_scendiff.tokens.encoding import encode_agent_tokens, pad_tokens
    from sumo_scendiff.train.loop import token_loss_weights
    # window centre -> a middle cell; corners -> the corner cells (row 0 is the window's +y edge); a
    # token without a position weighs nothing
    xy = np.array([[0.1, 0.1], [-49.0, 49.0], [49.0, -49.0], [20.0, 20.0]])
    tok = encode_agent_tokens({"x": xy[:, 0], "y": xy[:, 1], "speed": np.ones(4)},
                              {"x": np.array([1, 1, 1, 0], bool), "y": np.array([1, 1, 1, 0], bool),
                               "speed": np.ones(4, bool)})
    tokens, pad = pad_tokens([tok])
    w = token_loss_weights(tokens, pad, 16, 4.0)[0, 0]
    assert (w == 5.0).sum() == 3 and w[0, 0] == 5.0 and w[15, 15] == 5.0 and w[7:9, 7:9].max() == 5.0
    # a uniform weight is the plain loss; a weight on one cell moves the loss towards that cell's error
    torch.manual_seed(0)
    z0 = torch.randn(2, 4, 16, 16)

    def denoiser(z, sigma, **_):
        out = torch.zeros_like(z)
        out[:, :, 3, 5] = 10.0   # one cell very wrong
        return out
    loss = EDMLoss()
    sigma = torch.tensor([1.0, 1.0])
    gen = [torch.Generator().manual_seed(1) for _ in range(3)]
    plain = loss(denoiser, z0, sigma=sigma, generator=gen[0])
    uniform = loss(denoiser, z0, sigma=sigma, generator=gen[1], weight=torch.full((2, 1, 16, 16), 3.0))
    w = torch.ones(2, 1, 16, 16)
    w[:, :, 3, 5] = 5.0
    weighted = loss(denoiser, z0, sigma=sigma, generator=gen[2], weight=w)
    assert torch.allclose(plain, uniform) and (weighted > plain * 1.5).all()
