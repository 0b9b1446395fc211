"""GenerationConfig: the one definition of the generation settings, read by run, evaluate and sweep."""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import pkgutil
from dataclasses import replace

import numpy as np
import pytest

import sumo_scendiff
from sumo_scendiff.generation.config import (
    SAMPLER_NAMES,
    GenerationConfig,
    SettingError,
)

# every setting away from its default, as flags and as the config they must give
FLAGS = ["--steps", "3", "--sampler", "heun", "--eta", "0.8", "--threshold", "0.5", "--guidance", "1.5",
         "--plain-guidance", "--scene-guidance", "2.0", "--scene-guidance-sigma", "0.7", "--no-pin-tokens",
         "--no-pin-calibration", "--no-pin-speeds", "--no-lane-headings", "--no-lane-snap",
         "--no-deliver-tokens", "--signals", "--signal-guidance", "2.5", "--no-match-density", "--density-floor", "0.2",
         "--infill-passes", "1", "--binned-token-values", "--no-red-queues"]
CHANGED = GenerationConfig(steps=3, sampler="heun", eta=0.8, threshold=0.5, guidance=1.5, local_guidance=False, scene_guidance=2.0,
                           scene_guidance_sigma=0.7, pin_tokens=False, pin_calibration=False,
                           pin_speeds=False, lane_headings=False, lane_snap=False, deliver_tokens=False,
                           signals=True, signal_guidance=2.5, match_density=False, density_floor=0.2, infill_passes=1,
                           exact_token_values=False, red_queues=False)
RECORD_KEYS = ["sha256", "sampler", "steps", "eta", "threshold", "pin_tokens", "pin_speeds", "lane_headings",
               "lane_snap", "guidance", "local_guidance", "scene_guidance", "scene_guidance_sigma", "deliver_tokens", "signals", "signal_guidance",
               "red_queues", "match_density", "density_floor", "infill_passes", "exact_token_values"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    GenerationConfig.add_arguments(p)
    return p


def test_flags_round_trip_into_the_config():
    assert GenerationConfig.from_options(_parser().parse_args([])) == GenerationConfig()
    cfg = GenerationConfig.from_options(_parser().parse_args(FLAGS))
    assert cfg == CHANGED
    # every setting differs from its default in FLAGS: none is forgotten by the flags
    assert all(getattr(cfg, k) != getattr(GenerationConfig(), k) for k in GenerationConfig.settings())
    # not user settings: the batch size, and the count rule the command sets from what was asked
    assert set(GenerationConfig.settings()) == {f.name for f in dataclasses.fields(GenerationConfig)} - {
        "batch_size", "count_on_edges"}


def test_help_shows_the_defaults_and_bad_flags_name_the_flag(capsys):
    text = " ".join(_parser().format_help().split())
    for shown in ("--steps STEPS", "(default: 10)", "{dpmpp-2m,euler,heun,euler-ancestral,dpmpp-2m-sde}", "(default: dpmpp-2m)",
                  "(default: 0.8)", "(default: 3.0)", "--no-pin-calibration", "--no-lane-snap"):
        assert shown in text
    for bad, flag in ((["--steps", "0"], "--steps"), (["--threshold", "0"], "--threshold"),
                      (["--threshold", "1.5"], "--threshold"), (["--guidance", "-1"], "--guidance"),
                      (["--scene-guidance-sigma", "-0.1"], "--scene-guidance-sigma")):
        with pytest.raises(SettingError, match=f"^{flag}: must be"):
            GenerationConfig.from_options(_parser().parse_args(bad))
    with pytest.raises(SystemExit):
        _parser().parse_args(["--sampler", "rk4"])
    capsys.readouterr()


@pytest.mark.parametrize("table, key, problem", [
    ({"stpes": 4}, "stpes", "unknown key"),
    ({"steps": 2.5}, "steps", "must be int"),
    ({"steps": True}, "steps", "must be int"),
    ({"pin_tokens": 1}, "pin_tokens", "must be bool"),
    ({"guidance": "3"}, "guidance", "must be float"),
    ({"sampler": "rk4"}, "sampler", "must be one of dpmpp-2m, euler, heun"),
    ({"steps": 0}, "steps", "must be >= 1"),
    ({"threshold": 0}, "threshold", "must be > 0"),
    ({"threshold": 1.2}, "threshold", "must be <= 1"),
    ({"scene_guidance": -1.0}, "scene_guidance", "must be >= 0"),
    ({"guidance": float("nan")}, "guidance", "must be >= 0"),
])
def test_from_mapping_names_the_source_and_key(table, key, problem):
    with pytest.raises(SettingError) as e:
        GenerationConfig.from_mapping(table, "spec.toml")
    assert isinstance(e.value, ValueError)
    assert str(e.value).startswith(f"spec.toml: {key}: {problem}") and "\n" not in str(e.value)


def test_from_mapping_reads_numbers_as_their_kind():
    cfg = GenerationConfig.from_mapping({"threshold": 1, "guidance": 2, "sampler": "euler"}, "s.json")
    assert cfg == replace(GenerationConfig(), threshold=1.0, guidance=2.0, sampler="euler")
    assert type(cfg.threshold) is float and type(cfg.guidance) is float
    assert GenerationConfig.from_mapping({}, "s.json") == GenerationConfig()
    with pytest.raises(SettingError, match="^guidance: must be >= 0"):
        GenerationConfig(guidance=-1.0).validate()
    assert CHANGED.validate() is CHANGED


def test_sampler_names_are_the_models_solvers():
    from sumo_scendiff.model.edm import SAMPLERS, STOCHASTIC, sample_dpmpp_2m
    assert sorted(SAMPLER_NAMES) == sorted(SAMPLERS)
    assert GenerationConfig().sampler == SAMPLER_NAMES[0] and GenerationConfig().solver() is sample_dpmpp_2m
    for name in SAMPLER_NAMES:
        solver = GenerationConfig(sampler=name, eta=0.3).solver()
        if SAMPLERS[name] in STOCHASTIC:         # with the config's share of fresh noise
            assert solver.func is SAMPLERS[name] and solver.keywords == {"eta": 0.3}
            assert solver.__name__ == SAMPLERS[name].__name__
        else:
            assert solver is SAMPLERS[name]


@pytest.fixture(scope="module")
def generator():
    from sumo_scendiff.generation.generator import ScenarioGenerator
    return ScenarioGenerator.load()


def test_record_is_the_scene_records_model_block(generator):
    rec = GenerationConfig().record(generator)
    assert list(rec) == RECORD_KEYS
    assert rec["sha256"] == generator.sha256 and rec["sampler"] == "sample_dpmpp_2m"
    # None: the checkpoint's calibrated weight and interval, written resolved
    assert (rec["scene_guidance"], rec["scene_guidance_sigma"]) == (generator.scene_guidance,
                                                                   generator.scene_guidance_sigma)
    rec = CHANGED.record(generator)
    assert rec["sampler"] == "sample_heun" and (rec["scene_guidance"], rec["scene_guidance_sigma"]) == (2.0, 0.7)
    assert {k: rec[k] for k in RECORD_KEYS[4:10]} == {k: getattr(CHANGED, k) for k in RECORD_KEYS[4:10]}
    # the share of fresh noise only where the sampler draws it
    assert rec["steps"] == 3 and rec["eta"] is None
    assert replace(CHANGED, sampler="dpmpp-2m-sde").record(generator)["eta"] == 0.8


def test_the_sampler_name_chooses_the_solver_the_generator_runs(generator, cross_net):
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.map.network import Network
    net = Network.load(cross_net)
    w = [Window(0.0, 0.0, 0.0)]
    base = replace(GenerationConfig(), steps=2, threshold=0.01, lane_snap=False, lane_headings=False)
    out = {s: generator.generate(net, w, seed=1, config=replace(base, sampler=s))[0] for s in SAMPLER_NAMES}
    again = generator.generate(net, w, seed=1, config=replace(base, sampler="euler"))[0]
    assert np.array_equal(out["euler"].boxes, again.boxes)
    assert not np.array_equal(out["euler"].meta["score"], out["heun"].meta["score"])


def test_run_evaluate_and_sweep_take_their_defaults_from_the_one_class(cross_net, tmp_path):
    from sumo_scendiff.evaluate.__main__ import get_options as evaluate_options
    from sumo_scendiff.run import get_options as run_options
    from sumo_scendiff.sim.request import counted_as_asked
    from sumo_scendiff.sweep.spec import load_spec
    default = GenerationConfig()
    for o in (run_options(["-n", "x.net.xml"]), evaluate_options([])):
        assert GenerationConfig.from_options(o) == default
        flags = o.parser._option_string_actions
        for name in GenerationConfig.settings():
            assert flags[GenerationConfig.flag(name)].dest == name
    assert GenerationConfig.from_options(run_options(["-n", "x.net.xml"] + FLAGS)) == CHANGED
    assert GenerationConfig.from_options(evaluate_options(FLAGS)) == CHANGED
    spec = tmp_path / "bare.toml"
    spec.write_text(f'networks = ["{cross_net}"]\nlocations = [{{center = [0.0, 0.0]}}]\n')
    (s,) = load_spec(str(spec)).scenarios()
    # a window not given a vehicle count is counted as SUMO's edgeData counts, in sweeps as in run
    counted = counted_as_asked(default, None)
    assert s.generation == counted and counted.count_on_edges
    assert {k: s.params()[k] for k in GenerationConfig.settings()} == \
        {k: getattr(counted, k) for k in GenerationConfig.settings()} and "batch_size" not in s.params()
    spec.write_text(spec.read_text() + 'sampler = "euler"\npin_calibration = false\n')
    (s,) = load_spec(str(spec)).scenarios()
    assert s.generation == replace(counted, sampler="euler", pin_calibration=False) and s.sampler == "euler"


def test_no_function_takes_a_mutable_config_instance_as_its_default():
    """A default argument is one object shared by every call: a config given that way must be frozen."""
    bad = []
    for info in pkgutil.walk_packages(sumo_scendiff.__path__, "sumo_scendiff."):
        if ".train" in info.name:   # the training application has its own configs
            continue
        mod = importlib.import_module(info.name)
        for _, obj in inspect.getmembers(mod, lambda o: inspect.isfunction(o) or inspect.isclass(o)):
            if getattr(obj, "__module__", None) != mod.__name__:
                continue
            funcs = [obj] if inspect.isfunction(obj) else \
                [f for f in vars(obj).values() if inspect.isfunction(getattr(f, "__func__", f))]
            for f in funcs:
                f = getattr(f, "__func__", f)
                for p in inspect.signature(f).parameters.values():
                    d = p.default
                    if dataclasses.is_dataclass(d) and not isinstance(d, type) \
                            and not type(d).__dataclass_params__.frozen:
                        bad.append(f"{mod.__name__}.{f.__qualname__}({p.name}=)")
    assert not bad, bad
