"""Generation settings: the one place that defines them, their defaults, help and ranges.

    cfg = GenerationConfig(steps=20, sampler="euler")
    GenerationConfig.add_arguments(parser)                 # --steps, --sampler, ..., --no-lane-snap
    cfg = GenerationConfig.from_options(parser.parse_args())
    cfg = GenerationConfig.from_mapping(spec_table, "sweep.toml")   # a sweep spec's keys
    info["model"] = cfg.record(generator)                  # the scene record's "model" block

Torch-free, so that a command line's ``--help`` does not load the model: the sampler is a name,
turned into its solver (:data:`~sumo_scendiff.model.edm.SAMPLERS`) where the generator samples.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field, fields

# model.edm.SAMPLERS' keys (tests/test_generation_config.py holds them equal), default first
SAMPLER_NAMES = ("dpmpp-2m", "euler", "heun", "euler-ancestral", "dpmpp-2m-sde")
# the lights' guidance weight, chosen on the held-out generated networks (docs/model.md)
SIGNAL_GUIDANCE_DEFAULT = 8.0


class SettingError(ValueError):
    """One line: where the setting came from (a file, or the flag), the key, the problem."""


def _setting(default, help: str, *, kind: type, minimum: float | None = None, above: float | None = None,
             maximum: float | None = None, choices: tuple | None = None, flag: str | None = None):
    """A user setting: its default, help text and range, read by the flags, specs and checks."""
    return field(default=default, metadata={"help": help, "kind": kind, "minimum": minimum, "above": above,
                                            "maximum": maximum, "choices": choices, "flag": flag})


@dataclass(frozen=True)
class GenerationConfig:
    # DPM-Solver++(2M) at 10 steps: the quality of 20 Euler steps (the paper's solver) at half the
    # UNet passes (docs/model.md)
    steps: int = _setting(10, "ODE solver steps", kind=int, minimum=1)
    sampler: str = _setting(SAMPLER_NAMES[0], "solver of model.edm (dpmpp-2m: DPM-Solver++(2M); "
                            "euler: the paper's; euler-ancestral, dpmpp-2m-sde: stochastic, fresh noise "
                            "at every step, --eta of it)", kind=str, choices=SAMPLER_NAMES)
    eta: float = _setting(0.5, "share of fresh noise per step of a stochastic sampler (0: its ODE; 1: "
                          "ancestral sampling)", kind=float, minimum=0.0, maximum=1.0)
    threshold: float = _setting(0.8, "box probability threshold (paper sec. 4.1)", kind=float,
                                above=0.0, maximum=1.0)
    batch_size: int = 32         # windows per model call (not a user setting)
    # a requested density counts only the vehicles whose front is on a normal edge, as SUMO's edgeData
    # density counts them (a density in veh/km); off: every vehicle (a count of vehicles: --vehicles,
    # a demand's own vehicles). Set by the command from what was asked, not a user setting
    count_on_edges: bool = False
    # a second UNet pass only for batches that carry tokens
    guidance: float = _setting(3.0, "classifier-free guidance weight of the agent tokens (1 = off)",
                               kind=float, minimum=0.0)
    local_guidance: bool = _setting(
        True, "the agent tokens' guidance as the paper's, over the whole window (default: local, only "
        "around the tokens' vehicles, and projected, so the rest of the traffic is the model's and a "
        "token's vehicle is not drawn faster than it asks; docs/model.md)", kind=bool, flag="--plain-guidance")
    scene_guidance: float | None = _setting(
        None, "classifier-free guidance weight of the global token for windows without agent tokens: "
        "more agents above 1 (default: the model's calibrated value; 1 = off)", kind=float, minimum=0.0)
    scene_guidance_sigma: float | None = _setting(
        None, "apply the global token's guidance only above this noise level (default: the model's, "
        "calibrated with the weight)", kind=float, minimum=0.0)
    pin_tokens: bool = _setting(
        True, "tokens are conditions only, as in the paper (default: a token giving pose, size and "
        "speed -- every vehicle already in the window -- is pinned in the latent where it is, "
        "generation/pinning.py)", kind=bool, flag="--no-pin-tokens")
    pin_calibration: bool = _setting(
        True, "draw pinned tokens at the speeds they ask (default: at the speeds the decoder turns "
        "into the token's, pinning.calibrated_pins; README \"The model\")", kind=bool,
        flag="--no-pin-calibration")
    pin_speeds: bool = _setting(
        True, "a pinned token's vehicle keeps the speeds and path the model draws, what the paper's "
        "Table 3 measures (default: it moves along that path at the token's speed and final speed and "
        "turns by its heading_to_final, pinning.pace_to_pins)", kind=bool, flag="--no-pin-speeds")
    deliver_tokens: bool = _setting(
        True, "a token missing a pinning feature is a condition only, its vehicle as the model draws "
        "it or absent (default: the generated vehicle matched to it takes the speed, final speed, "
        "turn, heading and size it gives, and a positioned token no vehicle matches is placed on its "
        "lane, generation/deliver.py)", kind=bool, flag="--no-deliver-tokens")
    exact_token_values: bool = _setting(
        True, "the decoder reads a token's speed, final speed and turn as the centre of its bin, as in "
        "training (default: the exact values a token that is not pinned gives; the diffusion model "
        "reads the bins either way, tokens/raster.py)", kind=bool, flag="--binned-token-values")
    lane_headings: bool = _setting(
        True, "vehicles on a junction keep the decoder's own heading (default: the heading of the "
        "network's lane through them that the heading head finds most probable, lane_heading.py)",
        kind=bool, flag="--no-lane-headings")
    signals: bool = _setting(
        False, "the model sees each traffic light's state at the seeding moment, from the simulation "
        "(map/signals.py: queues at red, flows through green); off by default: on the hand-off "
        "benchmark the lights gave no fewer collisions (docs/evaluation.md)", kind=bool, flag="--signals")
    signal_guidance: float = _setting(
        SIGNAL_GUIDANCE_DEFAULT, "with --signals: how strongly the scene follows the lights' states "
        "(classifier-free guidance against the same map without them; 1 = off, twice the UNet passes "
        "otherwise)", kind=float, minimum=0.0)
    match_density: bool = _setting(
        True, "a requested density (--density/--vehicles) is a condition only: the scene holds the "
        "vehicles the model draws above --threshold (default: the window holds the requested count, "
        "round(density x car-lane km), the most probable boxes kept down to --density-floor)",
        kind=bool, flag="--no-match-density")
    density_floor: float = _setting(0.05, "lowest box probability a requested density may keep to "
                                    "reach its count", kind=float, above=0.0, maximum=1.0)
    infill_passes: int = _setting(2, "drawings again, with the vehicles so far pinned, of a window short of "
                                  "its requested count (generation/infill.py; 0: none)", kind=int, minimum=0)
    red_queues: bool = _setting(
        True, "with --signals: the vehicles the model draws slowing in a red light's queue keep its "
        "speeds (default: a queue at red stands, as SUMO's does, red_queues.py)", kind=bool,
        flag="--no-red-queues")
    lane_snap: bool = _setting(
        True, "vehicles keep their decoded pose (default: a pose within 3 m of an agreeing car lane "
        "moves onto its centre line and takes its heading, as SUMO's traffic drives; a vehicle on no "
        "such lane is removed unless a token put it there, lane_snap.py)", kind=bool,
        flag="--no-lane-snap")

    # ---- the settings ---------------------------------------------------------------------
    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The user settings' names (flags, spec keys), in order."""
        return tuple(f.name for f in fields(cls) if "help" in f.metadata)

    @classmethod
    def flag(cls, name: str) -> str:
        """The command-line flag of a setting."""
        meta = {f.name: f.metadata for f in fields(cls)}[name]
        return meta["flag"] or "--" + name.replace("_", "-")

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser):
        """Add every setting's flag (dest: the field's name) to ``parser``; returns the group."""
        group = parser.add_argument_group("generation")
        for f in fields(cls):
            m = f.metadata
            if "help" not in m:
                continue
            if m["kind"] is bool:   # the flag turns the default around
                group.add_argument(cls.flag(f.name), dest=f.name, help=m["help"],
                                   action="store_false" if f.default else "store_true")
                continue
            shown = "" if f.default is None else " (default: %(default)s)"
            group.add_argument(cls.flag(f.name), dest=f.name, type=m["kind"], default=f.default,
                               choices=m["choices"], help=m["help"] + shown,
                               metavar=None if m["choices"] else f.name.split("_")[-1].upper())
        return group

    @classmethod
    def from_options(cls, options) -> GenerationConfig:
        """The config of parsed flags (:meth:`add_arguments`); a bad value raises
        :class:`SettingError` naming the flag."""
        cfg = cls(**{name: getattr(options, name) for name in cls.settings()})
        for name, problem in cfg._problems():
            raise SettingError(f"{cls.flag(name)}: {problem}")
        return cfg

    @classmethod
    def from_mapping(cls, table: dict, source: str) -> GenerationConfig:
        """The config of a table of settings (a sweep spec's keys; absent keys: the defaults). An
        unknown key, a wrong type or a value out of range raises :class:`SettingError` naming
        ``source`` and the key."""
        meta = {f.name: f.metadata for f in fields(cls) if "help" in f.metadata}
        values = {}
        for key, v in table.items():
            if key not in meta:
                raise SettingError(f"{source}: {key}: unknown key (expected {', '.join(meta)})")
            kind = meta[key]["kind"]
            if kind is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
                raise SettingError(f"{source}: {key}: must be {kind.__name__}, got {v!r}")
            values[key] = v
        cfg = cls(**values)
        for name, problem in cfg._problems():
            raise SettingError(f"{source}: {name}: {problem}")
        return cfg

    def validate(self) -> GenerationConfig:
        """This config, or :class:`SettingError` for the first setting out of range."""
        for name, problem in self._problems():
            raise SettingError(f"{name}: {problem}")
        return self

    def _problems(self):
        for f in fields(self):
            m, v = f.metadata, getattr(self, f.name)
            if "help" not in m or v is None:
                continue
            if m["choices"] and v not in m["choices"]:
                yield f.name, f"must be one of {', '.join(m['choices'])}, got {v!r}"
            elif m["minimum"] is not None and not v >= m["minimum"]:
                yield f.name, f"must be >= {m['minimum']:g}, got {v!r}"
            elif m["above"] is not None and not v > m["above"]:
                yield f.name, f"must be > {m['above']:g}, got {v!r}"
            elif m["maximum"] is not None and not v <= m["maximum"]:
                yield f.name, f"must be <= {m['maximum']:g}, got {v!r}"

    # ---- use ------------------------------------------------------------------------------
    def solver(self):
        """The sampler's function (:data:`~sumo_scendiff.model.edm.SAMPLERS`)."""
        import functools

        from ..model.edm import SAMPLERS, STOCHASTIC
        fn = SAMPLERS[self.sampler]
        if fn in STOCHASTIC:
            return functools.update_wrapper(functools.partial(fn, eta=self.eta), fn)
        return fn

    def record(self, generator) -> dict:
        """The scene record's "model" block: the checkpoint and what this config generates with
        (the global token's guidance resolved against the checkpoint's calibrated values)."""
        return {"sha256": generator.sha256, "sampler": self.solver().__name__, "steps": self.steps,
                "eta": self.eta if self.sampler in ("euler-ancestral", "dpmpp-2m-sde") else None,
                "threshold": self.threshold, "pin_tokens": self.pin_tokens, "pin_speeds": self.pin_speeds,
                "lane_headings": self.lane_headings, "lane_snap": self.lane_snap, "guidance": self.guidance,
                "local_guidance": self.local_guidance, "scene_guidance": generator.scene_guidance_for(self),
                "scene_guidance_sigma": generator.scene_guidance_sigma_for(self),
                "deliver_tokens": self.deliver_tokens, "signals": self.signals,
                "signal_guidance": self.signal_guidance, "red_queues": self.red_queues,
                "match_density": self.match_density, "density_floor": self.density_floor,
                "infill_passes": self.infill_passes, "exact_token_values": self.exact_token_values}
