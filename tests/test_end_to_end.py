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

TINY_AE = {"enc_channels": [8, 8, 16, 16], "dec_channels": [16, 16, 16], "C_map": 8}
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


def test_train_then_sample_finds_the_trained_agent(tmp_path, cross_net):
    data = str(tmp_path / "data")
    scene = one_scene_dataset(data, cross_net)
    common = ["--data", data, data, "--val", data, "--batch-size", 1, "--no-rotate", "--val-every", 100,
              "--val-batches", 1, "--ckpt-every", 100]
    train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 300, "--lr", 3e-3,
          "--model-config", json.dumps(TINY_AE))
    train("diffusion", *common, "-o", tmp_path / "diff", "--steps", 300, "--lr", 2e-3,
          "--autoencoder", tmp_path / "ae" / "last.pt", "--model-config", json.dumps(TINY_DIFF))
    out = tmp_path / "model.pt"
    train("export", "--autoencoder", tmp_path / "ae" / "last.pt", "--diffusion", tmp_path / "diff" / "last.pt",
          "-o", out)

    from sumo_scendiff.evaluate.metrics import match_agents
    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    gen = ScenarioGenerator.load(str(out), GenerationConfig(steps=10, threshold=0.5))
    net = Network.load(cross_net)
    token = [{"x": -12.0, "y": float(scene.boxes[0, 1]), "heading": 0.0, "length": 4.6, "width": 1.8}]
    a = gen.generate(net, [scene.window] * 2, tokens=[token, token], p_mask=0.0, seed=5)
    again = gen.generate(net, [scene.window] * 2, tokens=[token, token], p_mask=0.0, seed=5)
    assert all(np.array_equal(x.boxes, y.boxes) for x, y in zip(a, again))  # same seed, same scenes
    b = gen.generate(net, [scene.window], tokens=[token], p_mask=0.0, seed=5)
    assert np.allclose(a[0].boxes, b[0].boxes, atol=1e-4)  # and (to float rounding) whatever the batch
    gi, ti = match_agents(a[0].boxes[:, :3], scene.boxes[:, :3])
    assert len(gi) == 1, (a[0].boxes, scene.boxes)
    assert abs(a[0].boxes[gi[0], 3] - 4.6) < 1.0 and 0.5 < a[0].boxes[gi[0], 4] < 4.0  # a tiny, short-trained model
    # resuming a finished run is a no-op that keeps the checkpoint's step
    res = train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 300, "--lr", 3e-3,
                "--model-config", json.dumps(TINY_AE))
    assert "resuming at step 300" in res.stdout


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
    assert proc.returncode == 0 and "stopped by signal" in out
    from sumo_scendiff.model import checkpoint as ckpt
    step = ckpt.load(str(tmp_path / "ae" / "last.pt"), "autoencoder-train")["step"]
    assert step > 0  # steps made before the signal are kept although no periodic checkpoint ran
    res = train("autoencoder", "--data", data, "-o", tmp_path / "ae", "--steps", step + 2, "--batch-size", 1,
                "--model-config", json.dumps(TINY_AE))
    assert f"resuming at step {step}" in res.stdout


def test_init_from_warm_starts_a_wider_unet(tmp_path, cross_net):
    """--init-from: a diffusion run without the token splat that read 11 map channels continues as
    one with the splat, every map channel and the density condition, computing the same function at
    its first step (new input channels of the UNet, of E_m and of the global token's embeddings
    start at zero) with the same latent scale."""
    import torch

    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
    data = str(tmp_path / "data")
    one_scene_dataset(data, cross_net)
    common = ["--data", data, "--batch-size", 1, "--no-rotate"]
    train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 2, "--model-config", json.dumps(TINY_AE))
    narrow = {**TINY_DIFF, "C_m": 11, "unet": {**TINY_DIFF["unet"], "splat_ch": 0, "global_dim": 10}}
    ae = ["--autoencoder", tmp_path / "ae" / "last.pt"]
    train("diffusion", *common, *ae, "-o", tmp_path / "d0", "--steps", 3, "--model-config", json.dumps(narrow))
    one_scene_dataset(str(tmp_path / "busy"), cross_net, xs=(-40.0, -25.0, -12.0))  # another latent std
    res = train("diffusion", "--data", tmp_path / "busy", "--batch-size", 1, "--no-rotate", *ae,
                "-o", tmp_path / "d1", "--steps", 0,
                "--init-from", tmp_path / "d0" / "last.pt", "--model-config", json.dumps(TINY_DIFF))
    assert "warm start from step 3" in res.stdout
    nets = []
    for run in ("d0", "d1"):
        ck = ckpt.load(str(tmp_path / run / "last.pt"), "diffusion-train")
        model = ScenarioDiffusion(ckpt.config_from_dict(DiffusionConfig, ck["model_config"]))
        model.load_state_dict(ck["ema"] if run == "d0" else ck["state"])  # warm starts take the average
        nets.append(model.eval())
    assert nets[1].cfg.unet.splat_ch == 16 and ck["init_from_sha256"] == ckpt.sha256(str(tmp_path / "d0" / "last.pt"))
    d0 = ckpt.load(str(tmp_path / "d0" / "last.pt"), "diffusion-train")
    assert ck["latent_scale"] == d0["latent_scale"]  # same autoencoder: the scale carries over
    w0, w1 = (n.denoiser.net.conv_in.weight for n in nets)
    assert torch.equal(w1[:, : w0.shape[1]], w0) and w1.shape[1] == w0.shape[1] + 16
    assert not w1[:, w0.shape[1]:].any()
    assert (nets[0].cfg.C_m, nets[1].cfg.C_m) == (11, 21)
    e0, e1 = (n.E_m.conv_in.weight for n in nets)
    assert torch.equal(e1[:, :11], e0) and not e1[:, 11:].any()
    g = torch.Generator().manual_seed(0)
    z, m = torch.randn(2, 4, 16, 16, generator=g), torch.randn(2, nets[1].cfg.C_m, 128, 128, generator=g)
    tok = torch.rand(2, 3, 170, generator=g)
    from sumo_scendiff.tokens.encoding import global_token
    pad = torch.zeros(2, 3, dtype=torch.bool)
    globs = [torch.as_tensor(global_token([0.3, 0.8], dim=n.cfg.unet.global_dim)) for n in nets]
    assert (nets[0].cfg.unet.global_dim, nets[1].cfg.unet.global_dim) == (10, 23)
    assert not nets[1].denoiser.net.global_emb.weight[:, 10:].any()
    with torch.no_grad():
        out = [n.denoiser(z, 1.0, **n.cond(m, tok, pad, g)) for n, g in zip(nets, globs)]
    torch.testing.assert_close(out[1], out[0], atol=1e-5, rtol=1e-5)


def test_fixed_lr_drop_and_weight_average_reach_the_export(tmp_path, cross_net, monkeypatch):
    """--lr-drop-at divides the learning rate by ten at that step (and again after a resume); the
    diffusion run keeps an EMA of its weights, which the export ships."""
    import torch

    from sumo_scendiff.model import checkpoint as ckpt
    data = str(tmp_path / "data")
    one_scene_dataset(data, cross_net)
    common = ["--data", data, "--batch-size", 1, "--no-rotate"]
    train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 2, "--model-config", json.dumps(TINY_AE))
    diff = [*common, "--autoencoder", tmp_path / "ae" / "last.pt", "-o", tmp_path / "d", "--lr", 1e-3,
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
    train("export", "--autoencoder", tmp_path / "ae" / "last.pt", "--diffusion", tmp_path / "d" / "last.pt",
          "-o", out)
    shipped = ckpt.load(str(out), "scenario-diffusion")
    assert shipped["trained"]["diffusion_ema"]
    assert all(torch.equal(shipped["diffusion"][k], ck["ema"][k]) for k in ck["ema"])
    # the calibrated scene guidance travels with the weights; a GenerationConfig value overrides it
    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    assert ScenarioGenerator.load(str(out)).scene_guidance == 1.0
    train("export", "--autoencoder", tmp_path / "ae" / "last.pt", "--diffusion", tmp_path / "d" / "last.pt",
          "-o", out, "--force", "--scene-guidance", 1.7, "--scene-guidance-sigma", 1.0)
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


def autoencoder_and_diffusion(tmp_path, cross_net, **model) -> tuple[list, object]:
    """A one-scene dataset, a 2-step autoencoder (tmp_path/ae) and a 1-step diffusion model on it
    (tmp_path/d), both with ``model`` config fields on top: the training flags shared by both, and
    the autoencoder's last.pt."""
    data = str(tmp_path / "data")
    one_scene_dataset(data, cross_net)
    common = ["--data", data, "--batch-size", 1, "--no-rotate"]
    train("autoencoder", *common, "-o", tmp_path / "ae", "--steps", 2,
          "--model-config", json.dumps({**TINY_AE, **model}))
    src = tmp_path / "ae" / "last.pt"
    train("diffusion", *common, "--autoencoder", src, "-o", tmp_path / "d", "--steps", 1,
          "--model-config", json.dumps({**TINY_DIFF, **model}))
    return common, src


def test_calibrate_writes_the_guidance_weight_into_the_model(tmp_path, cross_net):
    """train calibrate: map-only generation at each weight, the weight where the agents per window
    meet the ground truth's (to one decimal) rewritten into the exported file — for a model with the
    density condition (the default architecture) as the weight of windows given a density, the
    exported scene guidance kept; bad data: exit 2, the file untouched."""
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.train.calibrate import calibrate
    _, src = autoencoder_and_diffusion(tmp_path, cross_net)
    model = str(tmp_path / "model.pt")
    train("export", "--autoencoder", src, "--diffusion", tmp_path / "d" / "last.pt", "-o", model,
          "--scene-guidance-sigma", 1)
    exported = ckpt.sha256(model)
    exported_guidance = ckpt.load(model, "scenario-diffusion")["scene_guidance"]
    options = ["--data", tmp_path / "data", "--scenes", 2, "--weights", 1, 2, 3, "--steps", 2, "--turned"]
    res = train("calibrate", "--model", model, *options)
    ck = ckpt.load(model, "scenario-diffusion")
    # the same calibration in-process (the sampling does not depend on the stored weight)
    expected = calibrate(model, str(tmp_path / "data"), scenes=2, weights=(1, 2, 3), steps=2, turned=True)
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


def test_decoder_only_fine_tune_keeps_the_latent_space(tmp_path, cross_net):
    """--init-from with --freeze-encoder: the encoder's weights stay bit-identical, the decoder
    trains, the run inherits its source's config (and keeps it when resumed), and a diffusion model
    trained on the source autoencoder exports with the fine-tuned one; without --init-from: exit 2."""
    import torch

    from sumo_scendiff.model import checkpoint as ckpt
    common, src = autoencoder_and_diffusion(tmp_path, cross_net)
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
    train("export", "--autoencoder", tmp_path / "dec" / "last.pt", "--diffusion", tmp_path / "d" / "last.pt",
          "-o", tmp_path / "model.pt")
    assert ckpt.load(str(tmp_path / "model.pt"), "scenario-diffusion")["trained"]["autoencoder_steps"] == 2 + 5
    # the no-map ablation's decoder (scripts/train_nomap.sh): the source's config with use_map off
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


def test_decoder_fine_tune_adds_map_skips_map_channels_and_a_heading_head(tmp_path, cross_net):
    """--freeze-encoder with '{"map_skips": true, "C_m": 21, "heading_bins": 8}' from a model that
    read the first 11 map channels (before the lane-direction histogram) and had no heading head:
    the new skip projections, map-channel weights and head channels start at zero, so at learning
    rate 0 the decoder still computes its source's 19 outputs; the 11-channel diffusion model trained
    on the source exports and samples with it."""
    import torch

    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    from sumo_scendiff.map.raster import MAP_CHANNELS
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder
    common, src = autoencoder_and_diffusion(tmp_path, cross_net, C_m=11)
    train("autoencoder", *common, "-o", tmp_path / "dec", "--steps", 2, "--init-from", src, "--freeze-encoder",
          "--lr", 0.0, "--model-config", json.dumps({"map_skips": True, "C_m": len(MAP_CHANNELS), "heading_bins": 8}))
    a, b = (ckpt.load(str(p), "autoencoder-train") for p in (src, tmp_path / "dec" / "last.pt"))
    assert b["model_config"]["map_skips"] and not a["model_config"].get("map_skips")
    assert (a["model_config"]["C_m"], b["model_config"]["C_m"]) == (11, len(MAP_CHANNELS)) == (11, 21)
    w_a, w_b = a["state"]["D_down.conv_in.weight"], b["state"]["D_down.conv_in.weight"]
    assert torch.equal(w_b[:, :11], w_a) and not w_b[:, 11:].any()
    head = ("D_up.conv_out.weight", "D_up.conv_out.bias")
    assert all(torch.equal(b["state"][k][:19], a["state"][k]) and not b["state"][k][19:].any() for k in head)
    assert b["state"][head[0]].shape[0] == 19 + 2 * 8
    assert all(torch.equal(a["state"][k], b["state"][k]) for k in a["state"]
               if k not in ("D_down.conv_in.weight", *head))
    assert any(k.startswith("D_up.skips.") for k in b["state"])
    ae_a, ae_b = (ScenarioAutoencoder(ckpt.config_from_dict(AutoencoderConfig, c["model_config"])).eval()
                  for c in (a, b))
    ae_a.load_state_dict(a["state"])
    ae_b.load_state_dict(b["state"])
    x, m = torch.rand(1, 15, 128, 128), torch.rand(1, len(MAP_CHANNELS), 128, 128)
    with torch.no_grad():
        torch.testing.assert_close(ae_a(x, m)[0], ae_b(x, m)[0][:, :19], atol=1e-5, rtol=1e-5)
    out = tmp_path / "model.pt"
    train("export", "--autoencoder", tmp_path / "dec" / "last.pt", "--diffusion", tmp_path / "d" / "last.pt",
          "-o", out)
    gen = ScenarioGenerator.load(str(out), GenerationConfig(steps=2))
    assert gen.ae.cfg.map_skips and gen.ae.cfg.heading_bins == 8 and (gen.ae.cfg.C_m, gen.diffusion.cfg.C_m) == (21, 11)
    assert len(gen.generate(Network.load(cross_net), [Window(0.0, 0.0, 0.0)], seed=0)) == 1


def test_decoder_fine_tune_learns_to_read_the_tokens(tmp_path, cross_net):
    """--freeze-encoder with '{"C_t": 13}', --p-mislead, --p-counterfactual and --token-lr-scale: the decoder's token inputs
    start at zero and are trained (the encoder bit-identical), and the run resumes with its two
    optimiser groups, the export with the diffusion model of the source's latent loads,
    and generation hands the decoder the tokens' raster; another C_t is one line and exit 2."""
    import torch

    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.tokens.raster import C_T
    common, src = autoencoder_and_diffusion(tmp_path, cross_net)
    train("autoencoder", *common, "-o", tmp_path / "dec", "--steps", 3, "--init-from", src, "--freeze-encoder",
          "--p-keep-all-tokens", 1.0, "--p-mislead", 1.0, "--p-counterfactual", 0.5, "--token-lr-scale", 10,
          "--model-config", json.dumps({"C_t": C_T}))
    a, b = (ckpt.load(str(p), "autoencoder-train") for p in (src, tmp_path / "dec" / "last.pt"))
    assert b["model_config"]["C_t"] == C_T and not a["model_config"].get("C_t")
    assert all(torch.equal(a["state"][k], b["state"][k]) for k in a["state"] if k.startswith("E."))
    tokens = [k for k in b["state"] if k.startswith("D_up.tokens.")]
    assert len(tokens) == 6 and any(b["state"][k].any() for k in tokens if k.endswith("weight"))
    own, fast = b["optimizer"]["param_groups"]
    assert len(fast["params"]) == 6 and fast["lr"] == pytest.approx(10 * own["lr"])
    train("autoencoder", *common, "-o", tmp_path / "dec", "--steps", 4, "--init-from", src, "--freeze-encoder",
          "--token-lr-scale", 10, "--model-config", json.dumps({"C_t": C_T}))
    out = tmp_path / "model.pt"
    train("export", "--autoencoder", tmp_path / "dec" / "last.pt", "--diffusion", tmp_path / "d" / "last.pt",
          "-o", out)
    gen = ScenarioGenerator.load(str(out), GenerationConfig(steps=2))
    seen = []
    gen.ae.D_up.tokens["5"].register_forward_hook(lambda mod, inp, res: seen.append(float(inp[0].abs().sum())))
    scenes = gen.generate(Network.load(cross_net), [Window(0.0, 0.0, 0.0)], seed=0,
                          tokens=[[{"x": -12.0, "y": -1.6, "speed": 5.0}]])
    assert len(scenes) == 1 and seen and seen[-1] > 0
    # --token-weights-only with --exact-token-values: only the token inputs' weights move
    train("autoencoder", *common, "-o", tmp_path / "tw", "--steps", 2, "--init-from", tmp_path / "dec" / "last.pt",
          "--freeze-encoder", "--p-keep-all-tokens", 1.0, "--token-lr-scale", 10, "--exact-token-values",
          "--token-weights-only", "--model-config", json.dumps({"C_t": C_T}))
    c, d = (ckpt.load(str(p), "autoencoder-train")["state"] for p in (tmp_path / "dec" / "last.pt",
                                                                       tmp_path / "tw" / "last.pt"))
    moved = {k for k in c if not torch.equal(c[k], d[k])}
    assert moved and all(k.startswith("D_up.tokens.") and k.endswith(".weight") for k in moved)
    # --token-branch-only: a token branch added to the decoder and only it learning; a scene
    # without tokens decodes exactly as the decoder it was added to
    train("autoencoder", *common, "-o", tmp_path / "tb", "--steps", 2, "--init-from", tmp_path / "dec" / "last.pt",
          "--freeze-encoder", "--p-keep-all-tokens", 1.0, "--lr", 0.01, "--token-branch-only",
          "--model-config", json.dumps({"C_t": C_T, "token_branch": 8}))
    e = ckpt.load(str(tmp_path / "tb" / "last.pt"), "autoencoder-train")["state"]
    moved = {k for k in e if k not in c or not torch.equal(c[k], e[k])}
    assert any(k.startswith("D_up.branch.conv_out.") for k in moved)
    assert all(k.startswith("D_up.branch.") for k in moved)
    train("export", "--autoencoder", tmp_path / "tb" / "last.pt", "--diffusion", tmp_path / "d" / "last.pt",
          "-o", tmp_path / "branch.pt")
    with_branch = ScenarioGenerator.load(str(tmp_path / "branch.pt"), GenerationConfig(steps=2))
    assert with_branch.ae.D_up.branch is not None
    (a_scene,), (b_scene,) = (g.generate(Network.load(cross_net), [Window(0.0, 0.0, 0.0)], seed=1)
                              for g in (gen, with_branch))
    assert np.array_equal(a_scene.boxes, b_scene.boxes) and np.array_equal(a_scene.traj, b_scene.traj)
    bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "autoencoder", *map(str, common), "-o",
                          str(tmp_path / "x"), "--steps", "1", "--model-config", '{"C_t": 5}'],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "C_t 5: the token raster has 13 channels" in bad.stderr
    assert "Traceback" not in bad.stderr
    bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "autoencoder", *map(str, common), "-o",
                          str(tmp_path / "y"), "--steps", "1", "--token-branch-only", "--model-config",
                          json.dumps({"C_t": C_T})], capture_output=True, text=True)
    assert bad.returncode == 2 and "--token-branch-only: the decoder has no token branch" in bad.stderr


def test_grown_latent_warm_starts_both_stages(tmp_path, cross_net):
    """--model-config '{"C_z": 6}' with --init-from a C_z 4 autoencoder grows its latent (at
    learning rate 0 the old channels decode as before); a diffusion run on it takes c_z 6 from the
    autoencoder by itself and warm-starts from the 4-channel diffusion model; the pair exports and
    generates. Growing with --freeze-encoder, or shrinking, is one line and exit 2."""
    import torch

    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    from sumo_scendiff.model import checkpoint as ckpt
    common, src = autoencoder_and_diffusion(tmp_path, cross_net)
    train("autoencoder", *common, "-o", tmp_path / "ae6", "--steps", 1, "--init-from", src, "--lr", 0.0,
          "--weight-decay", 0.0, "--model-config", json.dumps({"C_z": 6}))
    a, b = (ckpt.load(str(p), "autoencoder-train") for p in (src, tmp_path / "ae6" / "last.pt"))
    assert b["model_config"]["C_z"] == 6
    w_a, w_b = a["state"]["E.conv_out.weight"], b["state"]["E.conv_out.weight"]
    assert torch.equal(w_b[:4], w_a[:4]) and torch.equal(w_b[6:10], w_a[4:])      # mu, logvar
    assert torch.equal(w_b[4:6], w_a[:2]) and torch.equal(w_b[10:], w_a[4:6])     # the copies
    d_a, d_b = a["state"]["D_up.conv_in.weight"], b["state"]["D_up.conv_in.weight"]
    assert torch.equal(d_b[:, :4], d_a[:, :4]) and not d_b[:, 4:6].any() and torch.equal(d_b[:, 6:], d_a[:, 4:])
    res = train("diffusion", *common, "--autoencoder", tmp_path / "ae6" / "last.pt", "--init-from",
                tmp_path / "d" / "last.pt", "-o", tmp_path / "d6", "--steps", 1, "--model-config", json.dumps(TINY_DIFF))
    assert "warm start from step 1" in res.stdout
    d6 = ckpt.load(str(tmp_path / "d6" / "last.pt"), "diffusion-train")
    assert d6["model_config"]["unet"]["c_z"] == 6
    out = tmp_path / "model.pt"
    train("export", "--autoencoder", tmp_path / "ae6" / "last.pt", "--diffusion", tmp_path / "d6" / "last.pt", "-o", out)
    gen = ScenarioGenerator.load(str(out), GenerationConfig(steps=2))
    assert len(gen.generate(Network.load(cross_net), [Window(0.0, 0.0, 0.0)], seed=0)) == 1
    for args, message in (
            (["--init-from", src, "--freeze-encoder", "--model-config", json.dumps({"C_z": 6})],
             "--freeze-encoder keeps the latent space"),
            (["--init-from", tmp_path / "ae6" / "last.pt", "--model-config", json.dumps({"C_z": 4})],
             "cannot shrink the latent from 6 to 4 channels")):
        bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "autoencoder", *map(str, common),
                              "-o", str(tmp_path / "bad"), "--steps", "1", *map(str, args)],
                             capture_output=True, text=True)
        assert bad.returncode == 2 and message in bad.stderr and "Traceback" not in bad.stderr, bad.stderr
        assert not (tmp_path / "bad" / "last.pt").exists()


def test_fine_tune_the_exported_model(tmp_path, cross_net):
    """An exported model (the shipped weights) is a warm start: its autoencoder serves as --autoencoder,
    its weight average as --init-from, its latent scale carries over, and the fine-tuned run exports
    against it again (at learning rate 0 the weights come back unchanged, the steps add up)."""
    import torch

    from sumo_scendiff.model import checkpoint as ckpt
    common, src = autoencoder_and_diffusion(tmp_path, cross_net)
    model = tmp_path / "model.pt"
    train("export", "--autoencoder", src, "--diffusion", tmp_path / "d" / "last.pt", "-o", model, "--fp16")
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
