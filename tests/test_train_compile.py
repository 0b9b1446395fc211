"""torch.compile of the diffusion stage's step (train/compiling.py): the compiled blocks give
eager's loss and gradients, the checkpoints of a compiled run are the eager model's (plain keys, weights_only
loading) and resume under DDP, and a compiler that cannot run is one line, exit 2.

A first compile costs minutes of a loaded CPU, so the module compiles each graph once: one compiled run
serves the checkpoint checks, the in-process step has the runs' shapes and thread count, and every process
shares one inductor cache, where the later compiles (a resume's, each DDP process's) find the graphs."""
from __future__ import annotations

import copy
import glob
import json
import os
import shutil
import subprocess
import sys
from types import SimpleNamespace

import pytest
import torch

from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
from sumo_scendiff.model.checkpoint import config_from_dict
from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
from sumo_scendiff.map.raster import MAP_CHANNELS
from sumo_scendiff.train.compiling import compile_diffusion_stage
from tests.test_end_to_end import TINY_AE, TINY_DIFF, one_scene_dataset, train

# the end-to-end tiny models with the stride-2 stem (configs/scendiff_wide.json's): a level less to compile
AE = {**TINY_AE, "stem": "stride2"}
DIFF = {**TINY_DIFF, "stem": "stride2"}
BATCH = 2   # per process: the in-process step's batch is the runs'


@pytest.fixture(scope="module", autouse=True)
def compiling(tmp_path_factory):
    """torch.compile on here (conftest turns it off for the other tests), in process and subprocesses,
    with one inductor cache for the module's processes (a test session's own, empty at first)."""
    import torch._dynamo.config
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("TORCH_COMPILE_DISABLE", raising=False)
        mp.setattr(torch._dynamo.config, "disable", False)
        mp.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path_factory.mktemp("inductor")))
        yield


@pytest.fixture(scope="module")
def trained_ae(tmp_path_factory, cross_net, compiling):
    """A dataset of four copies of one scene (a batch for each of two DDP processes) and a 1-step
    autoencoder on it (eager: the autoencoder stages do not compile)."""
    root = tmp_path_factory.mktemp("compile_runs")
    data = str(root / "data")
    one_scene_dataset(data, cross_net)
    common = ["--data", *[data] * 2 * BATCH, "--batch-size", BATCH, "--no-rotate"]
    train("autoencoder", *common, "-o", root / "ae", "--steps", 1, "--model-config", json.dumps(AE))
    return SimpleNamespace(root=root, common=common, ae=root / "ae" / "last.pt")


def _traced_train(trace: str, *args, **kwargs):
    """``train`` with torch's structured trace of each process in the folder ``trace``."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TORCH_TRACE", trace)
        return train(*args, **kwargs)


@pytest.fixture(scope="module")
def compiled_run(trained_ae):
    """The diffusion stage compiled (the default): 2 steps in one process (its last.pt copied to
    first.pt), then resumed for a third as two DDP processes (``resumed``: its output; ``last``)."""
    root = trained_ae.root
    diff = [*trained_ae.common, "--autoencoder", trained_ae.ae, "-o", root / "d", "--model-config", json.dumps(DIFF)]
    _traced_train(str(root / "trace_first"), "diffusion", *diff, "--steps", 2)
    shutil.copy(root / "d" / "last.pt", root / "first.pt")
    resumed = _traced_train(str(root / "trace_resumed"), "diffusion", *diff, "--steps", 3,
                            runner=("torchrun", "--standalone", "--nproc_per_node", "2", "-m"))
    return SimpleNamespace(root=root, first=root / "first.pt", last=root / "d" / "last.pt", resumed=resumed)


def _tiny_models():
    torch.manual_seed(0)
    ae = ScenarioAutoencoder(config_from_dict(AutoencoderConfig, AE)).eval().requires_grad_(False)
    diff = ScenarioDiffusion(config_from_dict(DiffusionConfig, DIFF))
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


@pytest.fixture
def one_thread():
    """One torch thread, the training runs' (OMP_NUM_THREADS=1): inductor's CPU code, and so its cache
    key, depends on the thread count."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.slow   # a compile takes minutes on a loaded CPU (seconds once inductor's cache holds it)
def test_a_compiled_step_gives_the_eager_loss_and_gradients(one_thread):
    ae, diff = _tiny_models()
    ae_c, diff_c = copy.deepcopy(ae), copy.deepcopy(diff)
    compile_diffusion_stage(ae_c, diff_c)
    g = torch.Generator().manual_seed(1)
    x = (torch.rand(BATCH, ae.cfg.C_x, 128, 128, generator=g) > 0.95).float()
    m = (torch.rand(BATCH, len(MAP_CHANNELS), 128, 128, generator=g) > 0.7).float()
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
def test_a_compiled_runs_checkpoint_loads_and_resumes_under_ddp(compiled_run):
    """The diffusion stage (frozen E and E_m compiled, the default): its last.pt has the eager model's
    keys, loads with weights_only=True, and the run resumes as two DDP processes, whose checkpoint
    has them too."""
    keys = ScenarioDiffusion(config_from_dict(DiffusionConfig, DIFF)).state_dict().keys()
    first = torch.load(compiled_run.first, weights_only=True)
    assert first["step"] == 2 and first["world_size"] == 1 and first["train_config"]["compile"] is True
    assert first["state"].keys() == keys and first["ema"].keys() == keys
    assert "resuming at step 2" in compiled_run.resumed.stdout
    last = torch.load(compiled_run.last, weights_only=True)
    assert last["step"] == 3 and last["world_size"] == 2 and last["train_config"]["compile"] is True
    assert last["state"].keys() == keys and last["ema"].keys() == keys
    # every process compiled (from inductor's cache or not): its trace holds inductor's code
    for run, processes in (("trace_first", 1), ("trace_resumed", 2)):
        traces = glob.glob(str(compiled_run.root / run / "*.log"))
        compiled = [t for t in traces if '"inductor_output_code"' in open(t).read()]
        assert len(compiled) == processes, (run, traces)


@pytest.mark.slow
def test_a_compiler_that_cannot_run_is_one_line(tmp_path, trained_ae):
    """No C++ compiler for inductor: one line naming --no-compile, exit 2; with it the stage trains."""
    args = [sys.executable, "-m", "sumo_scendiff.train", "diffusion", *map(str, trained_ae.common), "--steps", "1",
            "--autoencoder", str(trained_ae.ae), "--model-config", json.dumps(DIFF)]
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
