"""A tiny end-to-end run of the real pipeline: train both stages through the CLI, export, then
generate with ScenarioGenerator and find the agent the model was trained to place. Also the same
training under torchrun with 2 CPU processes (DistributedDataParallel, gloo)."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.data.shards import net_entry, write_manifest, write_shard
from sumo_scendiff.map.network import Network

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

TINY_AE = {"enc_channels": [8, 8, 16, 16], "dec_channels": [16, 16, 16], "C_map": 8, "token_branch": 8}
TINY_DIFF = {"map_channels": [4, 8, 8, 8],
             "unet": {"channels": [16, 32, 32], "d_model": 32, "heads": 4, "c_map": 8}}


def one_scene_dataset(root: str, net_path: str, xs=(-12.0,)) -> Scene:
    """One window with one car (or one per ``xs``) driving on the eastbound lane west of the crossing."""
    net = Network.load(net_path)
    lane = next(ln for ln in net.lanes if ln.edge == "wc")
    y = float(lane.shape[0][1])
    window = Window(-30.0, 0.0, 0.0)
    n = len(xs)
    box = np.array([[x, y, 0.0, 4.6, 1.8] for x in xs])  # scene frame = world frame shifted by 30 m
    traj = np.array([[[x + 5.0 * t, y, 0.0] for t in (-2, -1, 0, 1, 2)] for x in xs])
    scene = Scene(window, box, traj, np.ones((n, 5), bool), np.full((n, 5), 5.0), np.zeros(n), "cross")
    os.makedirs(root)
    entry = write_shard(os.path.join(root, "shard-000-0000.npz"), [scene], 0)
    write_manifest(root, [net_entry(net_path, root, "cross")], [entry])
    return scene


def train(*args, runner=(sys.executable, "-m")):
    res = subprocess.run([*runner, "sumo_scendiff.train", *map(str, args)], capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert res.returncode == 0, res.stderr[-2000:]
    return res


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, cross_net):
    """A one-scene dataset, a 2-step autoencoder on it and a 1-step diffusion model in its latent
    space, trained once for the tests that start from them (each writes its own runs beside them in
    its tmp_path): ``data``, ``common`` (the training flags shared by both), ``ae`` and ``diff`` (their
    last.pt)."""
    from types import SimpleNamespace
    root = tmp_path_factory.mktemp("tiny_run")
    data = str(root / "data")
    one_scene_dataset(data, cross_net)
    common = ["--data", data, "--batch-size", 1, "--no-rotate"]
    train("autoencoder", *common, "-o", root / "ae", "--steps", 2, "--model-config", json.dumps(TINY_AE))
    train("diffusion", *common, "--autoencoder", root / "ae" / "last.pt", "-o", root / "d", "--steps", 1,
          "--model-config", json.dumps(TINY_DIFF))
    return SimpleNamespace(data=data, common=common, ae=root / "ae" / "last.pt", diff=root / "d" / "last.pt")


def test_train_then_sample_finds_the_trained_agent(tmp_path, cross_net):
    data = str(tmp_path / "data")
    scene = one_scene_dataset(data, cross_net)
    common = ["--data", data, data, "--val", data, "--batch-size", 1, "--no-rotate", "--val-every", 50,
              "--val-batches", 1, "--ckpt-every", 50]
    train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 100, "--lr", 3e-3,
          "--model-config", json.dumps(TINY_AE))
    train("diffusion", *common, "-o", tmp_path / "diff", "--steps", 100, "--lr", 2e-3,
          "--autoencoder", tmp_path / "ae" / "last.pt", "--model-config", json.dumps(TINY_DIFF))
    out = tmp_path / "model.pt"
    train("export", "--autoencoder", tmp_path / "ae" / "last.pt", "--diffusion", tmp_path / "diff" / "last.pt",
          "-o", out)

    from sumo_scendiff.evaluate.metrics import match_agents
    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    gen = ScenarioGenerator.load(str(out), GenerationConfig(steps=10, threshold=0.5))
    net = Network.load(cross_net)

    def trained_agent(generated):
        gi, _ = match_agents(generated.boxes[:, :3], scene.boxes[:, :3])
        assert len(gi) == 1, (generated.boxes, scene.boxes)
        # a tiny, short-trained model
        assert abs(generated.boxes[gi[0], 3] - 4.6) < 1.0 and 0.5 < generated.boxes[gi[0], 4] < 4.0
    # from the map alone: the model learned the car (an untrained one scatters cars over the other
    # lane and misses it; with the car's token it would find it through the pinning alone)
    trained_agent(gen.generate(net, [scene.window], seed=5)[0])
    token = [{"x": -12.0, "y": float(scene.boxes[0, 1]), "heading": 0.0, "length": 4.6, "width": 1.8}]
    a = gen.generate(net, [scene.window] * 2, tokens=[token, token], p_mask=0.0, seed=5)
    again = gen.generate(net, [scene.window] * 2, tokens=[token, token], p_mask=0.0, seed=5)
    assert all(np.array_equal(x.boxes, y.boxes) for x, y in zip(a, again))  # same seed, same scenes
    b = gen.generate(net, [scene.window], tokens=[token], p_mask=0.0, seed=5)
    assert np.allclose(a[0].boxes, b[0].boxes, atol=1e-4)  # and (to float rounding) whatever the batch
    trained_agent(a[0])
    # resuming a finished run is a no-op that keeps the checkpoint's step
    res = train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 100, "--lr", 3e-3,
                "--model-config", json.dumps(TINY_AE))
    assert "resuming at step 100" in res.stdout


@pytest.mark.skipif(shutil.which("torchrun") is None, reason="torchrun not installed")
def test_torchrun_two_cpu_processes(tmp_path, cross_net):
    data = str(tmp_path / "data")
    one_scene_dataset(data, cross_net)
    train("autoencoder", "--data", data, "-o", tmp_path / "ae", "--steps", 4, "--batch-size", 1,
                "--no-rotate", "--ckpt-every", 2, "--model-config", json.dumps(TINY_AE),
                runner=("torchrun", "--standalone", "--nproc_per_node", "2", "-m"))
    from sumo_scendiff.model import checkpoint as ckpt
    ck = ckpt.load(str(tmp_path / "ae" / "last.pt"), "autoencoder-train")
    assert ck["step"] == 4


def test_sigterm_saves_and_resume_continues(tmp_path, cross_net):
    import signal
    import time
    data = str(tmp_path / "data")
    one_scene_dataset(data, cross_net)
    args = [sys.executable, "-m", "sumo_scendiff.train", "autoencoder", "--data", data, "-o",
            str(tmp_path / "ae"), "--steps", "100000", "--batch-size", "1", "--ckpt-every", "100000",
            "--model-config", json.dumps(TINY_AE)]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    # signal once the progress bar shows a finished step (the handler is in place by then), however
    # slowly a loaded machine starts the process
    err, deadline = b"", time.time() + 300
    while not re.search(rb"\| [1-9]\d*/100000", err) and proc.poll() is None and time.time() < deadline:
        err += os.read(proc.stderr.fileno(), 4096)
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=60)
    out = out.decode()
    assert proc.returncode == 128 + signal.SIGTERM and "stopped by signal" in out  # not finished
    from sumo_scendiff.model import checkpoint as ckpt
    step = ckpt.load(str(tmp_path / "ae" / "last.pt"), "autoencoder-train")["step"]
    assert step > 0  # steps made before the signal are kept although no periodic checkpoint ran
    res = train("autoencoder", "--data", data, "-o", tmp_path / "ae", "--steps", step + 2, "--batch-size", 1,
                "--model-config", json.dumps(TINY_AE))
    assert f"resuming at step {step}" in res.stdout


def test_fixed_lr_drop_and_weight_average_reach_the_export(tmp_path, cross_net, tiny_run, monkeypatch):
    """--lr-drop-at divides the learning rate by ten at that step (and again after a resume); the
    diffusion run keeps an EMA of its weights, which the export ships."""
    import torch

    from sumo_scendiff.model import checkpoint as ckpt
    diff = [*tiny_run.common, "--autoencoder", tiny_run.ae, "-o", tmp_path / "d", "--lr", 1e-3,
            "--lr-drop-at", 3, "--model-config", json.dumps(TINY_DIFF)]
    train("diffusion", *diff, "--steps", 2)
    ck = ckpt.load(str(tmp_path / "d" / "last.pt"), "diffusion-train")
    assert ck["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-3)
    train("diffusion", *diff, "--steps", 5)  # resumes with --lr 1e-3 given again: the drop still holds
    ck = ckpt.load(str(tmp_path / "d" / "last.pt"), "diffusion-train")
    assert ck["step"] == 5 and ck["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-4)
    assert ck["ema"].keys() == ck["state"].keys()
    assert any(not torch.equal(ck["ema"][k], ck["state"][k]) for k in ck["state"])
    out = tmp_path / "model.pt"
    train("export", "--autoencoder", tiny_run.ae, "--diffusion", tmp_path / "d" / "last.pt", "-o", out)
    shipped = ckpt.load(str(out), "scenario-diffusion")
    assert shipped["trained"]["diffusion_ema"]
    assert all(torch.equal(shipped["diffusion"][k], ck["ema"][k]) for k in ck["ema"])
    # the calibrated scene guidance travels with the weights; a GenerationConfig value overrides it
    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    assert ScenarioGenerator.load(str(out)).scene_guidance == 1.0
    train("export", "--autoencoder", tiny_run.ae, "--diffusion", tmp_path / "d" / "last.pt", "-o", out,
          "--force", "--scene-guidance", 1.7, "--scene-guidance-sigma", 1.0)
    gen = ScenarioGenerator.load(str(out))
    assert gen.scene_guidance == pytest.approx(1.7) and gen.scene_guidance_sigma == pytest.approx(1.0)
    net = Network.load(cross_net)
    win = [Window(0.0, 0.0, 0.0)]
    # the sampled latents, unrounded: this barely trained model's guidance moves the boxes by less
    # than the millimetres scenes are rounded to (on some CPUs not at all)
    from sumo_scendiff.model.diffusion import ScenarioDiffusion
    latents, sample = [], ScenarioDiffusion.sample
    monkeypatch.setattr(ScenarioDiffusion, "sample", lambda *a, **k: latents.append(sample(*a, **k)) or latents[-1])
    for w, s in ((None, None), (1.7, 1.0), (1.0, None), (1.7, 0.0), (1.7, 100.0)):
        ScenarioGenerator.load(str(out), GenerationConfig(steps=3, threshold=0.0, scene_guidance=w,
                                                          scene_guidance_sigma=s)).generate(net, win, seed=1)
    a, b, c, d, e = latents
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert not torch.equal(a, d)     # guiding the low-noise steps too changes the scene
    assert torch.equal(e, c)         # guiding no step at all is no guidance


def test_calibrate_writes_the_guidance_weight_into_the_model(tmp_path, tiny_run):
    """train calibrate: map-only generation at each weight, the weight where the agents per window
    meet the ground truth's (to one decimal) rewritten into the exported file — for a model with the
    density condition (the default architecture) as the weight of windows given a density, the
    exported scene guidance kept; bad data: exit 2, the file untouched."""
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.train.calibrate import calibrate
    model = str(tmp_path / "model.pt")
    train("export", "--autoencoder", tiny_run.ae, "--diffusion", tiny_run.diff, "-o", model,
          "--scene-guidance-sigma", 1)
    exported = ckpt.sha256(model)
    exported_guidance = ckpt.load(model, "scenario-diffusion")["scene_guidance"]
    options = ["--data", tiny_run.data, "--scenes", 2, "--weights", 1, 2, 3, "--steps", 2, "--turned"]
    res = train("calibrate", "--model", model, *options)
    ck = ckpt.load(model, "scenario-diffusion")
    # the same calibration in-process (the sampling does not depend on the stored weight)
    expected = calibrate(model, tiny_run.data, scenes=2, weights=(1, 2, 3), steps=2, turned=True)
    assert ck["density_guidance"] == expected.weight == round(ck["density_guidance"], 1)
    assert 1 <= ck["density_guidance"] <= 3 and ck["scene_guidance_sigma"] == 1.0
    assert ck["scene_guidance"] == exported_guidance
    assert f"density guidance {expected.weight:g} above sigma 1" in res.stdout
    assert ckpt.sha256(model) != exported and not os.path.exists(model + ".partial")
    train("calibrate", "--model", model, *options, "--sigma", 0.5)
    assert ckpt.load(model, "scenario-diffusion")["scene_guidance_sigma"] == 0.5
    before = ckpt.sha256(model)
    bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "calibrate", "--model", model,
                          "--data", str(tmp_path)], capture_output=True, text=True)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "not a data directory" in bad.stderr
    assert ckpt.sha256(model) == before


def test_decoder_only_fine_tune_keeps_the_latent_space(tmp_path, tiny_run):
    """--init-from with --freeze-encoder: the encoder's weights stay bit-identical, the decoder
    trains, the run inherits its source's config (and keeps it when resumed), and a diffusion model
    trained on the source autoencoder exports with the fine-tuned one; without --init-from: exit 2."""
    import torch

    from sumo_scendiff.model import checkpoint as ckpt
    common, src = tiny_run.common, tiny_run.ae
    weights = json.dumps({"loss": {"category_weights": [1.0, 1.0, 4.0]}})
    fine = [*common, "-o", tmp_path / "dec", "--lr", 1e-2, "--model-config", weights]
    res = train("autoencoder", *fine, "--steps", 3, "--init-from", src, "--freeze-encoder")
    assert "warm start from step 2" in res.stdout
    train("autoencoder", *fine, "--steps", 5)  # resumed without the flags: still decoder-only
    a, b = (ckpt.load(str(p), "autoencoder-train") for p in (src, tmp_path / "dec" / "last.pt"))
    assert b["step"] == 5 and b["encoder_from_sha256"] == ckpt.sha256(str(src))
    assert tuple(b["model_config"]["enc_channels"]) == (8, 8, 16, 16)
    assert tuple(b["model_config"]["loss"]["category_weights"]) == (1.0, 1.0, 4.0)
    enc = [k for k in a["state"] if k.startswith("E.")]
    assert enc and all(torch.equal(a["state"][k], b["state"][k]) for k in enc)
    assert any(not torch.equal(a["state"][k], b["state"][k]) for k in a["state"] if k.startswith("D_up."))
    train("export", "--autoencoder", tmp_path / "dec" / "last.pt", "--diffusion", tiny_run.diff,
          "-o", tmp_path / "model.pt")
    assert ckpt.load(str(tmp_path / "model.pt"), "scenario-diffusion")["trained"]["autoencoder_steps"] == 2 + 5
    # the no-map ablation's decoder (configs/nomap.json): the source's config with use_map off
    train("autoencoder", *common, "-o", tmp_path / "nomap", "--steps", 3, "--init-from", src,
          "--freeze-encoder", "--no-map")
    c = ckpt.load(str(tmp_path / "nomap" / "last.pt"), "autoencoder-train")
    assert c["model_config"]["use_map"] is False and tuple(c["model_config"]["enc_channels"]) == (8, 8, 16, 16)
    assert all(torch.equal(a["state"][k], c["state"][k]) for k in enc)
    bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "autoencoder", *map(str, common),
                          "-o", str(tmp_path / "x"), "--steps", "1", "--freeze-encoder"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--freeze-encoder needs --init-from" in bad.stderr
    assert "Traceback" not in bad.stderr and not (tmp_path / "x" / "last.pt").exists()


def test_decoder_fine_tune_learns_to_read_the_tokens(tmp_path, cross_net, tiny_run):
    """--freeze-encoder with --p-mislead and --p-counterfactual: the decoder (its token inputs and
    branch among it) is trained with the encoder bit-identical, the run resumes, the export with the
    diffusion model of the source's latent loads, and generation hands the decoder the tokens'
    raster; another C_t, or another C_z than the source's, is one line and exit 2."""
    import torch

    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    from sumo_scendiff.model import checkpoint as ckpt
    common, src = tiny_run.common, tiny_run.ae
    train("autoencoder", *common, "-o", tmp_path / "dec", "--steps", 3, "--init-from", src, "--freeze-encoder",
          "--p-keep-all-tokens", 1.0, "--p-mislead", 1.0, "--p-counterfactual", 0.5, "--lr", 0.01)
    a, b = (ckpt.load(str(p), "autoencoder-train") for p in (src, tmp_path / "dec" / "last.pt"))
    assert all(torch.equal(a["state"][k], b["state"][k]) for k in a["state"] if k.startswith("E."))
    moved = {k for k in a["state"] if not torch.equal(a["state"][k], b["state"][k])}
    assert any(k.startswith("D_up.tokens.") for k in moved) and any(k.startswith("D_up.branch.") for k in moved)
    res = train("autoencoder", *common, "-o", tmp_path / "dec", "--steps", 4, "--init-from", src, "--freeze-encoder")
    assert "resuming at step 3" in res.stdout
    out = tmp_path / "model.pt"
    train("export", "--autoencoder", tmp_path / "dec" / "last.pt", "--diffusion", tiny_run.diff,
          "-o", out)
    gen = ScenarioGenerator.load(str(out), GenerationConfig(steps=2))
    seen = []
    gen.ae.D_up.tokens["5"].register_forward_hook(lambda mod, inp, res: seen.append(float(inp[0].abs().sum())))
    scenes = gen.generate(Network.load(cross_net), [Window(0.0, 0.0, 0.0)], seed=0,
                          tokens=[[{"x": -12.0, "y": -1.6, "speed": 5.0}]])
    assert len(scenes) == 1 and seen and seen[-1] > 0
    for args, message in ((["--model-config", '{"C_t": 5}'], "C_t 5: the token raster has 13 channels"),
                          (["--init-from", src, "--model-config", '{"C_z": 6}'], "C_z 6 differs from")):
        bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "autoencoder", *map(str, common), "-o",
                              str(tmp_path / "x"), "--steps", "1", *map(str, args)], capture_output=True, text=True)
        assert bad.returncode == 2 and message in bad.stderr and "Traceback" not in bad.stderr, bad.stderr
        assert not (tmp_path / "x" / "last.pt").exists()


def test_fine_tune_the_exported_model(tmp_path, tiny_run):
    """An exported model (the shipped weights) is a warm start: its autoencoder serves as --autoencoder,
    its weight average as --init-from, its latent scale carries over, and the fine-tuned run exports
    against it again (at learning rate 0 the weights come back unchanged, the steps add up)."""
    import torch

    from sumo_scendiff.model import checkpoint as ckpt
    common, src = tiny_run.common, tiny_run.ae
    model = tmp_path / "model.pt"
    train("export", "--autoencoder", src, "--diffusion", tiny_run.diff, "-o", model, "--fp16")
    res = train("diffusion", *common, "--autoencoder", model, "--init-from", model, "-o", tmp_path / "ft",
                "--steps", 2, "--lr", 0.0, "--weight-decay", 0.0, "--model-config", json.dumps(TINY_DIFF))
    assert "warm start from step 1" in res.stdout
    train("export", "--autoencoder", model, "--diffusion", tmp_path / "ft" / "last.pt", "-o", tmp_path / "again.pt")
    a, b = (ckpt.load(str(p), "scenario-diffusion") for p in (model, tmp_path / "again.pt"))
    assert b["latent_scale"] == a["latent_scale"]
    assert b["trained"]["diffusion_steps"] == 1 + 2 and b["trained"]["autoencoder_steps"] == 2
    for part in ("autoencoder", "diffusion"):
        assert all(torch.equal(b[part][k].half(), a[part][k]) for k in a[part])
    # a decoder fine-tuned from the run (not from the exported file) keeps the encoder: it fits
    train("autoencoder", *common, "--init-from", src, "--freeze-encoder", "-o", tmp_path / "dec", "--steps", 1,
          "--model-config", json.dumps(TINY_AE))
    train("export", "--autoencoder", tmp_path / "dec" / "last.pt", "--diffusion", model, "-o", tmp_path / "dec.pt")
    # another encoder does not
    train("autoencoder", *common, "-o", tmp_path / "other", "--steps", 1, "--seed", 1,
          "--model-config", json.dumps(TINY_AE))
    bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "export", "--autoencoder",
                          str(tmp_path / "other" / "last.pt"), "--diffusion", str(model), "-o", str(tmp_path / "x.pt")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "was trained on another autoencoder" in bad.stderr
    assert "Traceback" not in bad.stderr and not (tmp_path / "x.pt").exists()
