"""One window request (sim/request.py) for run, sweeps and the co-simulation API: the p_mask rule,
the density target and the tokens, on a real SUMO running a small demand."""
from __future__ import annotations

import pytest

ROUTES = ('<routes><flow id="f" begin="0" end="400" period="3" from="wc" to="ce"/>'
          '<flow id="g" begin="0" end="400" period="5" from="sc" to="cn"/></routes>')


@pytest.fixture
def host(cross_net, tmp_path):
    """libsumo running the crossing's demand for 60 s, and the network."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.map.network import Network
    rou = tmp_path / "r.rou.xml"
    rou.write_text(ROUTES)
    libsumo.start([sumo_binary(), "-n", cross_net, "-r", str(rou), "--no-step-log", "true"])
    try:
        for _ in range(60):
            libsumo.simulationStep()
        yield libsumo, Network.load(cross_net)
    finally:
        libsumo.close()


def _request(sim, net, user=(), **kw):
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.sim.cosim import CoSimulation
    from sumo_scendiff.sim.request import window_request
    w = Window(0.0, 0.0, 0.0)
    existing = CoSimulation(sim, net, generator=None).existing(w)
    return window_request(net, sim, w, existing, user, **kw), existing


def test_p_mask_follows_the_windows_tokens_unless_given(host):
    """Given (flag, file key, sweep value, API argument): kept. Else 0.5 where the window has agent
    tokens -- the vehicles already there count -- and 1.0 in a window without any (docs/tokens.md)."""
    from sumo_scendiff.tokens.file import parse_tokens
    sim, net = host
    req, existing = _request(sim, net)
    assert existing.token_ids(), "the demand should have vehicles in the window at 60 s"
    assert req.p_mask == 0.5 and req.sources == existing.token_ids() and req.tokens == existing.tokens()
    assert _request(sim, net, p_mask=0.8)[0].p_mask == 0.8
    empty_file = parse_tokens({}, "t.toml")                 # a file without agents or p_mask
    assert empty_file.asked_p_mask() is None and empty_file.p_mask == 1.0
    assert _request(sim, net, empty_file.for_window(req.window), p_mask=empty_file.asked_p_mask())[0].p_mask == 0.5
    given = parse_tokens({"p_mask": 0.2}, "t.toml")
    assert _request(sim, net, p_mask=given.asked_p_mask())[0].p_mask == 0.2


def test_an_empty_window_asks_the_whole_scene(cross_net):
    """No host vehicles and no tokens: p_mask 1.0, no target without a host (the model's level)."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.map.network import Network
    libsumo.start([sumo_binary(), "-n", cross_net, "--no-step-log", "true"])
    try:
        req, _ = _request(libsumo, Network.load(cross_net), signals=True)
        assert (req.p_mask, req.target, req.tokens) == (1.0, None, [])
        assert req.lights and all(set(s) <= set("rugyGsoO") for s in req.lights.values())
    finally:
        libsumo.close()


def test_the_target_and_a_model_without_the_density_condition(host):
    """No level named: the host's own around the window; a number is the number; a target asked of a
    model without the condition raises DensityUnsupported carrying the target."""
    from sumo_scendiff.sim.density import host_density
    from sumo_scendiff.sim.request import DensityUnsupported, generation_inputs
    sim, net = host
    req, _ = _request(sim, net)
    assert req.target == pytest.approx(host_density(sim, net, req.window)) and req.target > 0
    assert _request(sim, net, host=False)[0].target is None           # a simulation without demand
    assert _request(sim, net, density=25.0)[0].target == 25.0
    assert _request(sim, net, has_density=False)[0].target is None    # the default: the model's level
    with pytest.raises(DensityUnsupported) as e:
        _request(sim, net, density=25.0, has_density=False)
    assert e.value.target == 25.0
    inputs = generation_inputs([req, _request(sim, net, density="model")[0]])
    assert inputs["density"] == [req.target, None] and inputs["p_mask"] == [0.5, 0.5]
