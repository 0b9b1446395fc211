"""Checkpoints: weights_only loading and one clear error for every kind of bad file."""
from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from sumo_scendiff.model import checkpoint as ckpt
from sumo_scendiff.model.autoencoder import AutoencoderConfig, ScenarioAutoencoder


def tiny_ae():
    return ScenarioAutoencoder(AutoencoderConfig(enc_channels=(4, 4, 4, 4), dec_channels=(4, 4, 4), C_map=4))


def test_round_trip_with_weights_only(tmp_path):
    ae = tiny_ae()
    path = str(tmp_path / "a.pt")
    sha = ckpt.save(path, "autoencoder-train", state=ae.state_dict(),
                    model_config=ckpt.config_to_dict(ae.cfg), step=3)
    assert len(sha) == 64 and sha == ckpt.sha256(path)
    ck = ckpt.load(path, "autoencoder-train")
    cfg = ckpt.config_from_dict(AutoencoderConfig, ck["model_config"])
    assert cfg == ae.cfg  # tuples restored, nested loss config restored
    again = ScenarioAutoencoder(cfg)
    ckpt.load_state(again, ck["state"], path)
    for (k, a), b in zip(ae.state_dict().items(), again.state_dict().values()):
        assert torch.equal(a, b), k


def _write(path, kind):
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        ae = tiny_ae()
        ckpt.save(str(path), "autoencoder-train", state=ae.state_dict(), model_config={})
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 3])
    elif kind == "text":
        path.write_text("hello")
    elif kind == "foreign":
        torch.save({"model": torch.zeros(3)}, str(path))
    elif kind == "pickled_code":
        torch.save({"format": "sumo-scendiff", "obj": torch.nn.Linear(2, 2)}, str(path))
    elif kind == "version":
        torch.save({"format": "sumo-scendiff", "version": 99, "kind": "autoencoder-train"}, str(path))
    elif kind == "kind":
        ckpt.save(str(path), "diffusion-train", state={})


@pytest.mark.parametrize("kind, words", [
    ("missing", "no such checkpoint"), ("empty", "empty file"), ("truncated", "not a readable"),
    ("text", "not a readable"), ("foreign", "not a sumo-scendiff checkpoint"),
    ("pickled_code", "not a readable"), ("version", "format version 99"),
    ("kind", "expected autoencoder-train")])
def test_bad_checkpoints(tmp_path, kind, words):
    path = tmp_path / "bad.pt"
    if kind != "missing":
        _write(path, kind)
    with pytest.raises(ckpt.CheckpointError) as e:
        ckpt.load(str(path), "autoencoder-train")
    assert str(path) in str(e.value) and words in str(e.value)
    assert "\n" not in str(e.value)


def test_weights_of_another_architecture(tmp_path):
    path = str(tmp_path / "a.pt")
    ckpt.save(path, "autoencoder-train", state=tiny_ae().state_dict())
    with pytest.raises(ckpt.CheckpointError, match="do not fit"):
        ckpt.load_state(ScenarioAutoencoder(AutoencoderConfig()), ckpt.load(path, "autoencoder-train")["state"], path)


def test_cli_bad_checkpoint_exit_2(tmp_path):
    bad = tmp_path / "x.pt"
    bad.write_text("not torch")
    res = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "export", "--autoencoder", str(bad),
                          "--diffusion", str(bad), "-o", str(tmp_path / "out.pt")], capture_output=True, text=True)
    assert res.returncode == 2 and "Traceback" not in res.stderr and "x.pt" in res.stderr
    assert not (tmp_path / "out.pt").exists()


def test_cli_token_mix_that_is_not_a_distribution_exit_2(tmp_path):
    res = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "diffusion", "--autoencoder", "a.pt",
                          "--data", str(tmp_path), "-o", str(tmp_path / "run"), "--p-keep-all-tokens", "0.5",
                          "--p-map-only", "0.6"], capture_output=True, text=True)
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert "--p-map-only 0.6" in res.stderr and not (tmp_path / "run").exists()


@pytest.mark.parametrize("flag", ["--scene-guidance", "--scene-guidance-sigma"])
def test_cli_export_negative_guidance_setting_exit_2(tmp_path, flag):
    res = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "export", "--autoencoder", "a.pt",
                          "--diffusion", "d.pt", "-o", str(tmp_path / "out.pt"), flag, "-1"],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert f"{flag} must be >= 0" in res.stderr and not (tmp_path / "out.pt").exists()


def test_update_replaces_entries_atomically(tmp_path):
    from sumo_scendiff.train.calibrate import write_scene_guidance
    path = str(tmp_path / "m.pt")
    state = tiny_ae().state_dict()
    before = ckpt.save(path, "scenario-diffusion", autoencoder=state, scene_guidance=1.0,
                       scene_guidance_sigma=1.0, trained={"autoencoder_steps": 3})
    after = write_scene_guidance(path, 1.4)
    ck = ckpt.load(path, "scenario-diffusion")
    assert after != before and after == ckpt.sha256(path)
    assert ck["scene_guidance"] == 1.4 and ck["scene_guidance_sigma"] == 1.0   # sigma kept unless given
    assert ck["trained"] == {"autoencoder_steps": 3} and all(torch.equal(ck["autoencoder"][k], v)
                                                             for k, v in state.items())
    write_scene_guidance(path, 2.0, sigma=0.5)
    ck = ckpt.load(path, "scenario-diffusion")
    assert (ck["scene_guidance"], ck["scene_guidance_sigma"]) == (2.0, 0.5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pt"]   # no .partial left behind
    ckpt.save(path, "autoencoder-train", state={})
    with pytest.raises(ckpt.CheckpointError, match="expected scenario-diffusion"):
        write_scene_guidance(path, 1.0)


@pytest.mark.parametrize("args, words", [
    (["--model", "nope.pt", "--data", "d"], "nope.pt: no such checkpoint"),
    (["--model", "m.pt", "--data", "d", "--scenes", "0"], "--scenes must be positive"),
    (["--model", "m.pt", "--data", "d", "--weights", "1", "-1"], "--weights and --sigma must be >= 0"),
])
def test_cli_calibrate_bad_input_exit_2(tmp_path, args, words):
    res = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "calibrate", *args],
                         capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert words in res.stderr


def _saved_config(tmp_path, name: str, **fields) -> str:
    """A version-1 autoencoder-train checkpoint whose stored config is ``fields`` (as an earlier
    version wrote it)."""
    path = str(tmp_path / name)
    torch.save({"format": ckpt.FORMAT, "version": 1, "kind": "autoencoder-train", "state": {},
                "model_config": fields, "step": 0}, path)
    return path


def test_a_config_an_earlier_version_stored_loads_as_it_was_trained(tmp_path):
    """Fields a config lacks take the value that model was trained with, not today's default; the
    retired switches, on in that model, are dropped."""
    path = _saved_config(tmp_path, "old.pt", C_m=11, map_skips=True, loss={"cls_weight": 20.0})
    cfg = ckpt.config_from_dict(AutoencoderConfig, ckpt.load(path, "autoencoder-train")["model_config"])
    assert (cfg.C_m, cfg.heading_bins, cfg.C_t, cfg.token_branch, cfg.kl_weight, cfg.latent_noise) == (11, 0, 0, 0, 0.1, 1.0)
    assert (cfg.loss.speed_weight, cfg.loss.category_weights, cfg.loss.box_weight) == (0.0, (0.1, 0.3, 4.0), 1.0)
    assert AutoencoderConfig().heading_bins == 16 and AutoencoderConfig().loss.speed_weight == 2.0


@pytest.mark.parametrize("fields, words", [
    ({"map_skips": False}, "map_skips False"),
    ({}, "map_skips False"),                                         # stored before map skips existed
    ({"map_skips": True, "C_t": 13, "token_speeds_filled": False}, "token_speeds_filled False"),
    ({"map_skips": True, "C_t": 13, "token_branch": 32, "token_speeds_filled": True}, "token_branch_mix False"),
])
def test_a_model_this_version_cannot_run_is_one_line_naming_the_file(tmp_path, fields, words):
    path = _saved_config(tmp_path, "retired.pt", **fields)
    with pytest.raises(ckpt.CheckpointError, match=words) as e:
        ckpt.load(path, "autoencoder-train")
    assert "retired.pt" in str(e.value) and "\n" not in str(e.value)


def test_the_shipped_checkpoint_reads_with_todays_defaults():
    """The shipped file stores every field; its configs are today's defaults (the retired switches
    were on), so the default model is the shipped architecture."""
    from sumo_scendiff.generation.generator import DEFAULT_CHECKPOINT
    from sumo_scendiff.model.diffusion import DiffusionConfig
    ck = ckpt.load(DEFAULT_CHECKPOINT, "scenario-diffusion")
    assert ckpt.config_from_dict(AutoencoderConfig, ck["autoencoder_config"]) == AutoencoderConfig()
    assert ckpt.config_from_dict(DiffusionConfig, ck["diffusion_config"]) == DiffusionConfig()
    raw = torch.load(DEFAULT_CHECKPOINT, weights_only=True)["autoencoder_config"]
    assert raw["map_skips"] and raw["token_speeds_filled"] and raw["token_branch_mix"]


def test_a_stride2_stem_round_trips_and_an_earlier_file_reads_as_the_full_stem(tmp_path):
    """A model saved with ``stem`` "stride2" loads (weights_only) into the same architecture and
    encodes the same; the shipped file, stored before the field existed, reads as the full stem and
    its weights fit the default model exactly (strict load)."""
    from sumo_scendiff.generation.generator import DEFAULT_CHECKPOINT
    from sumo_scendiff.model.diffusion import DiffusionConfig
    ae = ScenarioAutoencoder(AutoencoderConfig(enc_channels=(4, 4, 4, 4), dec_channels=(4, 4, 4), C_map=4,
                                               stem="stride2")).eval()
    path = str(tmp_path / "s.pt")
    ckpt.save(path, "autoencoder-train", state=ae.state_dict(), model_config=ckpt.config_to_dict(ae.cfg))
    ck = ckpt.load(path, "autoencoder-train")
    again = ScenarioAutoencoder(ckpt.config_from_dict(AutoencoderConfig, ck["model_config"])).eval()
    ckpt.load_state(again, ck["state"], path)
    x = torch.rand(1, 15, 128, 128)
    assert again.cfg.stem == "stride2" and torch.equal(again.encode(x)[0], ae.encode(x)[0])
    shipped = ckpt.load(DEFAULT_CHECKPOINT, "scenario-diffusion")
    assert "stem" not in torch.load(DEFAULT_CHECKPOINT, weights_only=True)["autoencoder_config"]
    cfg = ckpt.config_from_dict(AutoencoderConfig, shipped["autoencoder_config"])
    assert cfg.stem == "full" and ckpt.config_from_dict(DiffusionConfig, shipped["diffusion_config"]).stem == "full"
    ckpt.load_state(ScenarioAutoencoder(cfg), {k: v.float() for k, v in shipped["autoencoder"].items()}, DEFAULT_CHECKPOINT)
