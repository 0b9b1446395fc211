"""torch.compile of the diffusion stage's step (train/compiling.py): the compiled blocks give
eager's loss and gradients, the checkpoints of a compiled run are the eager model's (plain keys, weights_only
loading) and resume, two DDP processes run it, and a compiler that cannot run is one line, exit 2."""
from __future__ import annotations

import copy
import json
import os
import subprocess
import sys

import pytest
import torch

from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from sumo_scendiff.model.checkpoint import config_from_dict
from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
from sumo_scendiff.map.raster import MAP_CHANNELS
from sumo_scendiff.train.compiling import compile_diffusion_stage
from tests.test_end_to_end import TINY_AE, TINY_DIFF, one_scene_dataset, train


@pytest.fixture(autouse=True)
def compiling(monkeypatch):
    """torch.compile on here (conftest turns it off for the other tests), in process and subprocesses."""
    import torch._dynamo.config
    monkeypatch.delenv("TORCH_COMPILE_DISABLE", raising=False)
    monkeypatch.setattr(torch._dynamo.config, "disable", False)


def _tiny_models():
    torch.manual_seed(0)
    ae = ScenarioAutoencoder(config_from_dict(AutoencoderConfig, TINY_AE)).eval().requires_grad_(False)
    diff = ScenarioDiffusion(config_from_dict(DiffusionConfig, TINY_DIFF))
    return ae, diff


def _diffusion_step(ae, diff, x, m, seed: int):
    """The diffusion stage's loss (stages.train_diffusion's step_loss, no tokens) and gradients."""
    torch.manual_seed(seed)
    with torch.no_grad():
        z0 = ae.encode(x)[0]
    cfg = diff.cfg.unet
    loss = diff.loss(z0, m, torch.zeros(len(x), 0, cfg.agent_dim), torch.zeros(len(x), 0, dtype=torch.bool),
                     torch.zeros(len(x), cfg.global_dim))
    diff.zero_grad(set_to_none=True)
    loss.backward()
    return loss.detach(), {k: p.grad.clone() for k, p in diff.named_parameters() if p.grad is not None}


@pytest.mark.slow   # a compile takes minutes on a loaded CPU (seconds once inductor's cache holds it)
def test_a_compiled_step_gives_the_eager_loss_and_gradients():
    ae, diff = _tiny_models()
    ae_c, diff_c = copy.deepcopy(ae), copy.deepcopy(diff)
    compile_diffusion_stage(ae_c, diff_c)
    g = torch.Generator().manual_seed(1)
    x = (torch.rand(2, ae.cfg.C_x, 128, 128, generator=g) > 0.95).float()
    m = (torch.rand(2, len(MAP_CHANNELS), 128, 128, generator=g) > 0.7).float()
    for seed in (3, 4):   # the first call compiles, the second runs the compiled graphs
        loss, grads = _diffusion_step(ae, diff, x, m, seed)
        loss_c, grads_c = _diffusion_step(ae_c, diff_c, x, m, seed)
        torch.testing.assert_close(loss_c, loss, rtol=1e-5, atol=1e-6)
        assert grads_c.keys() == grads.keys() and any(k.startswith("E_m.") for k in grads)
        for k in grads:
            torch.testing.assert_close(grads_c[k], grads[k], rtol=1e-4, atol=1e-6)
    # eager without gradients (validation), and the weights are the eager module's
    with torch.no_grad():
        torch.testing.assert_close(diff_c.encode_map(m), diff.encode_map(m), rtol=1e-5, atol=1e-6)
    assert diff_c.state_dict().keys() == diff.state_dict().keys()


@pytest.mark.slow
def test_a_compiled_runs_checkpoint_loads_and_resumes_under_ddp(tmp_path, cross_net):
    """The diffusion stage (frozen E and E_m compiled, the default) as two DDP processes; its
    last.pt has the eager model's keys, loads with weights_only=True and the run resumes."""
    data = str(tmp_path / "data")
    one_scene_dataset(data, cross_net)
    common = ["--data", data, "--batch-size", 1, "--no-rotate"]
    train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 1, "--model-config", json.dumps(TINY_AE))
    diff = [*common, "--autoencoder", tmp_path / "ae" / "last.pt", "-o", tmp_path / "d",
            "--model-config", json.dumps(TINY_DIFF)]
    train("diffusion", *diff, "--steps", 2, runner=("torchrun", "--standalone", "--nproc_per_node", "2", "-m"))
    ck = torch.load(tmp_path / "d" / "last.pt", weights_only=True)
    assert ck["step"] == 2 and ck["world_size"] == 2 and ck["train_config"]["compile"] is True
    assert ck["state"].keys() == ScenarioDiffusion(config_from_dict(DiffusionConfig, TINY_DIFF)).state_dict().keys()
    assert ck["ema"].keys() == ck["state"].keys()
    res = train("diffusion", *diff, "--steps", 3)
    assert "resuming at step 2" in res.stdout
    assert torch.load(tmp_path / "d" / "last.pt", weights_only=True)["step"] == 3


@pytest.mark.slow
def test_a_compiler_that_cannot_run_is_one_line(tmp_path, cross_net):
    """No C++ compiler for inductor: one line naming --no-compile, exit 2; with it the stage trains."""
    data = str(tmp_path / "data")
    one_scene_dataset(data, cross_net)
    common = ["--data", data, "--batch-size", 1, "--no-rotate"]
    train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 1, "--model-config", json.dumps(TINY_AE))
    args = [sys.executable, "-m", "sumo_scendiff.train", "diffusion", *map(str, common), "--steps", "1",
            "--autoencoder", str(tmp_path / "ae" / "last.pt"), "--model-config", json.dumps(TINY_DIFF)]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "CXX": str(tmp_path / "no-such-compiler"),
           "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "cache")}   # nothing compiled before
    bad = subprocess.run([*args, "-o", str(tmp_path / "d")], capture_output=True, text=True, env=env)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr[-2000:]
    last = bad.stderr.strip().splitlines()[-1]
    assert "torch.compile of" in last and "--no-compile" in last
    ok = subprocess.run([*args, "-o", str(tmp_path / "d2"), "--no-compile"], capture_output=True, text=True, env=env)
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert torch.load(tmp_path / "d2" / "last.pt", weights_only=True)["train_config"]["compile"] is False


@pytest.mark.parametrize("flag", ["--compile", "--no-compile"])
def test_the_flag_is_a_training_setting(flag):
    from sumo_scendiff.train.__main__ import get_options
    from sumo_scendiff.train.stages import DIFFUSION_DEFAULTS, train_config
    o = get_options(["diffusion", "--data", "d", "-o", "o", "--autoencoder", "a", flag])
    assert train_config(o, DIFFUSION_DEFAULTS).compile is (flag == "--compile")
    assert DIFFUSION_DEFAULTS.compile    # on unless turned off
