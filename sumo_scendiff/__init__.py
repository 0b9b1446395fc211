"""Scenario Diffusion for SUMO: generate traffic scenes on a SUMO network and seed them as real SUMO
vehicles.

    from sumo_scendiff import Network, ScenarioGenerator, Window
    net = Network.load("networks/city.net.xml")
    scenes = ScenarioGenerator.load().generate(net, [Window(1020.0, 980.0, 0.0)], seed=0)

The public names are imported on first use, so ``import sumo_scendiff`` stays cheap (no torch, no
SUMO) for tools that only read scene files. docs/architecture.md says which room holds what.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    # core: frames and scenes
    "Window": "core.geometry", "Scene": "core.scene",
    # map
    "Network": "map.network", "NetworkError": "map.network", "render_map": "map.raster",
    "RasterConfig": "map.raster", "auto_windows": "map.locations", "window_at": "map.locations",
    "draw_scene": "map.picture",
    # tokens
    "load_tokens": "tokens.file", "parse_tokens": "tokens.file", "TokenFileError": "tokens.file",
    "TokenError": "tokens.features",
    # generation
    "ScenarioGenerator": "generation.generator", "GenerationConfig": "generation.config",
    "DEFAULT_CHECKPOINT": "generation.generator",
    # sim
    "SimConfig": "sim.sumo", "SimError": "sim.sumo", "SumoDied": "sim.sumo", "start": "sim.sumo", "Seeder": "sim.seeding",
    "CoSimulation": "sim.cosim", "Session": "sim.session", "ScenarioWriter": "sim.export",
    "rollout": "sim.rollout",
    # applications
    "load_spec": "sweep.spec", "evaluate_scenes": "evaluate.metrics", "LaneUniform": "evaluate.baselines",
    "CheckpointError": "model.checkpoint",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
