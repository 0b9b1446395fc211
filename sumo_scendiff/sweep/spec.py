"""Sweep spec files (TOML or JSON) and their expansion into scenarios.

    spec = load_spec("scenarios/truck_stopping.toml")
    scenarios = spec.scenarios()          # the cross product (or the explicit list), in a fixed order

The format is documented in ``docs/sweeps.md``; every key is checked (an unknown key or a wrong type
names the key and the file). A scenario is one (network, location, token set, p_mask, traffic level,
seed) with the
generation settings (:class:`~sumo_scendiff.generation.config.GenerationConfig`, whose fields are
also the spec's keys) and the rollout settings; its ``id`` is its position in the plan, so a resumed
sweep (same spec) finds the same ids.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
from dataclasses import asdict, dataclass, field
from typing import Any

from ..generation.config import GenerationConfig, SettingError

# the sweep's own keys; GenerationConfig.settings() are keys too, checked by GenerationConfig
KEYS = {"name": str, "networks": list, "locations": list, "token_sets": list, "p_mask": list,
        "seeds": (list, int), "rollout": float, "step_length": float, "replay": float, "scenarios": list,
        "density": list, "vehicles": list}
SWEEP_DEFAULTS = {"rollout": 60.0, "replay": 0.0}   # step_length: per network, sim.sumo.default_step_length
NET_KEYS = {"net": str, "config": str, "routes": (str, list), "additional": (str, list),
            "begin": (int, float, str)}
LOC_KEYS = {"auto": int, "center": list, "yaw": float}
SET_KEYS = {"name": str, "frame": str, "p_mask": float, "agents": list, "vary": dict}
SCENARIO_KEYS = {"network": str, "location": str, "token_set": str, "p_mask": float, "seed": int,
                 "density": None, "vehicles": None}


# a sweep's scenarios at most (docs/sweeps.md): a spec asking for more is a typo, not a plan,
# and its cross product would never end being listed
MAX_SCENARIOS = 100_000


class SpecError(ValueError):
    """One line: the spec file, the key, the problem."""


@dataclass(frozen=True)
class NetworkEntry:
    """A network entry as the spec gives it (absolute paths, no file read yet): a network, or a
    user's ``.sumocfg`` whose inputs ``net``/``routes``/``additional`` replace, as run's -n/-r/-a do
    with -c. :meth:`Spec.scenario_of` reads it as run reads its inputs."""
    name: str                    # file name without .net.xml (or .sumocfg); unique within the sweep
    net: str | None              # absolute path; None: the configuration's
    routes: tuple[str, ...] = ()
    begin: float | None = None   # the seeding time on SUMO's clock (default: first departure + 600 s)
    config: str | None = None
    additional: tuple[str, ...] = ()
    where: str = "networks[0]"   # the entry in the spec, for its errors


@dataclass(frozen=True)
class Scenario:
    """One scenario of the plan; its generation settings read as its own (``s.steps``)."""
    id: str
    network: str                 # NetworkEntry.name
    location: str                # "auto:K" or "X,Y" (or "X,Y,yaw")
    token_set: str
    p_mask: float | None         # None: the token set's own
    seed: int
    rollout: float
    step_length: float
    replay: float = 0.0          # seconds the agents follow their generated future first
    generation: GenerationConfig = field(default_factory=GenerationConfig)
    density: float | str | None = None   # veh per km of car lane, "auto", "model" or None (sim.density.default_density)
    vehicles: int | None = None          # vehicles in the window instead (exclusive with density)

    def __getattr__(self, name: str):
        # only for names the dataclass does not have; guarded so that unpickling (no attributes
        # yet) sees a plain AttributeError
        if name in GenerationConfig.settings() and "generation" in self.__dict__:
            return getattr(self.__dict__["generation"], name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def params(self) -> dict:
        """The scenario as a flat record (plan, index, scene.json): its generation settings beside
        its place and rollout."""
        own = {k: v for k, v in asdict(self).items() if k != "generation"}
        head = {k: own.pop(k) for k in ("id", "network", "location", "token_set", "p_mask", "density",
                                        "vehicles", "seed")}
        return {**head, **{k: getattr(self.generation, k) for k in GenerationConfig.settings()}, **own}


@dataclass
class Spec:
    source: str
    name: str
    networks: dict[str, NetworkEntry]
    locations: list[str]
    token_sets: dict[str, Any]   # name -> tokenfile.TokenSpec
    p_masks: list[float | None]
    seeds: list[int]
    settings: dict[str, float] = field(default_factory=dict)   # rollout, replay, step_length if given
    generation: GenerationConfig = field(default_factory=GenerationConfig)
    explicit: list[dict] | None = None
    digest: str = ""
    levels: list[tuple] = field(default_factory=lambda: [(None, None)])   # (density, vehicles) axis
    _scenarios: dict = field(default_factory=dict, repr=False, compare=False)   # scenario_of's, read once

    def scenario_of(self, network: str):
        """The network entry ``network`` as run reads -c/-n/-r/-a (``sim.scenario.scenario_from_files``:
        the configuration's inputs, time window, step length and options); a file it names that does
        not exist, or a configuration SUMO's reader refuses, is a :class:`SpecError` naming the entry."""
        if network not in self._scenarios:
            self._scenarios[network] = _read_entry(self.source, self.networks[network])
        return self._scenarios[network]

    def step_length_of(self, network: str) -> float:
        """The step a network entry runs at without the spec's ``step_length``: its configuration's,
        else SUMO's default with a demand or a configuration, the product's for a bare network
        (``sim.sumo.step_length_for``, as run takes it); a bare entry's files are not read here."""
        from ..sim.sumo import default_step_length, step_length_for
        entry = self.networks[network]
        if entry.config is None:
            return default_step_length(bool(entry.routes))
        return step_length_for(self.scenario_of(network))

    def auto_count(self) -> int:
        """How many automatic locations the sweep uses per network."""
        locs = self.locations + [e["location"] for e in (self.explicit or [])]
        idx = [int(loc[5:]) for loc in locs if loc.startswith("auto:")]
        return max(idx) + 1 if idx else 0

    def scenarios(self) -> list[Scenario]:
        if self.explicit is not None:
            combos = [(e["network"], e["location"], e["token_set"], e.get("p_mask"),
                       (e.get("density"), e.get("vehicles")), e["seed"]) for e in self.explicit]
        else:   # without density/vehicles the level axis is one (None, None): today's plan and ids
            axes = (self.networks, self.locations, self.token_sets, self.p_masks, self.levels, self.seeds)
            if math.prod(map(len, axes)) > MAX_SCENARIOS:
                raise SpecError(f"{self.source}: the cross product holds {math.prod(map(len, axes)):,} scenarios, "
                                f"more than {MAX_SCENARIOS:,}")
            combos = list(itertools.product(self.networks, self.locations, self.token_sets,
                                            self.p_masks, self.levels, self.seeds))
        if not combos:
            raise SpecError(f"{self.source}: the sweep is empty (a list in the cross product is empty)")
        from ..sim.request import counted_as_asked
        steps = {net: self.settings.get("step_length") or self.step_length_of(net) for net in {c[0] for c in combos}}
        return [Scenario(f"s{k:04d}", net, loc, ts, pm, seed,
                         **{**SWEEP_DEFAULTS, "step_length": steps[net], **self.settings},
                         generation=counted_as_asked(self.generation, level[1]), density=level[0], vehicles=level[1])
                for k, (net, loc, ts, pm, level, seed) in enumerate(combos)]


def _err(source: str, key: str, msg: str) -> SpecError:
    return SpecError(f"{source}: {key}: {msg}")


def _check_keys(source: str, where: str, table: Any, allowed: dict) -> dict:
    if not isinstance(table, dict):
        raise _err(source, where, "must be a table")
    for k, v in table.items():
        if k not in allowed:
            raise _err(source, f"{where}.{k}" if where else k,
                       f"unknown key (expected {', '.join(allowed)})")
        want = allowed[k]
        if want is None:   # checked by its owner
            continue
        if want is bool:
            ok = isinstance(v, bool)
        else:
            ok = isinstance(v, want) and not isinstance(v, bool) if want is not float else \
                isinstance(v, (int, float)) and not isinstance(v, bool)
        if not ok:
            names = "/".join(t.__name__ for t in (want if isinstance(want, tuple) else (want,)))
            raise _err(source, f"{where}.{k}" if where else k, f"must be {names}, got {v!r}")
    return table


def _paths(source: str, key: str, value, here: str) -> tuple[str, ...]:
    """A file or a list of files of a network entry, relative to the spec's folder."""
    value = [value] if isinstance(value, str) else value
    if not value or not all(isinstance(v, str) and v for v in value):
        raise _err(source, key, f"must be a path or a non-empty list of paths, got {value!r}")
    return tuple(os.path.normpath(os.path.join(here, v)) for v in value)


def _entry_name(net: str | None, config: str | None) -> str:
    """An entry's name: its network's file name without .net.xml, else its configuration's without
    .sumocfg (the name explicit scenarios give as ``network``)."""
    return os.path.basename(net).split(".net.xml")[0] if net else os.path.basename(config).split(".sumocfg")[0]


def _networks(source: str, raw: list, here: str) -> dict[str, NetworkEntry]:
    from ..sim.scenario import is_network_name
    out: dict[str, NetworkEntry] = {}
    for i, item in enumerate(raw):
        item = {"net": item} if isinstance(item, str) else item
        where = f"networks[{i}]"
        e = _check_keys(source, where, item, NET_KEYS)
        if "net" not in e and "config" not in e:
            raise _err(source, where, "needs 'net' or 'config'")
        files = {k: _paths(source, f"{where}.{k}", e[k], here) for k in NET_KEYS if k in e and k != "begin"}
        net, config = files.get("net", (None,))[0], files.get("config", (None,))[0]
        # each in its own key, as run's -n/-c (sim.scenario.input_flags_problem)
        if net and net.endswith(".sumocfg"):
            raise _err(source, f"{where}.net", f"{e['net']}: a SUMO configuration, not a network (give it as config)")
        if config and is_network_name(config):
            raise _err(source, f"{where}.config", f"{e['config']}: a SUMO network, not a configuration "
                       "(give it as net)")
        name = _entry_name(net, config)
        if name in out:
            name = f"{name}_{i}"
        out[name] = NetworkEntry(name, net, files.get("routes", ()), _begin(source, where, e.get("begin")), config,
                                 files.get("additional", ()), where)
    return out


def _begin(source: str, where: str, begin):
    """An entry's ``begin``, read as the CLIs' --begin (None: not given)."""
    if begin is None:
        return None
    from argparse import ArgumentTypeError

    from ..core.cli import sumo_time
    try:
        return sumo_time(str(begin))
    except ArgumentTypeError:
        raise _err(source, f"{where}.begin", f"must be a time >= 0 (s or H:MM:SS), got {begin!r}") from None


def _read_entry(source: str, entry: NetworkEntry):
    """Spec.scenario_of's reading: each file the entry names first (one line naming the entry and
    its key), then the configuration through run's reader."""
    from ..sim.scenario import ScenarioError, scenario_from_files
    for key, paths in (("config", [entry.config]), ("net", [entry.net]), ("routes", entry.routes),
                       ("additional", entry.additional)):
        for path in (p for p in paths if p):
            if not os.path.isfile(path):
                raise _err(source, f"{entry.where}.{key}", f"{path}: no such file")
    try:
        return scenario_from_files(entry.config, entry.net, entry.routes, entry.additional,
                                   replace_with="the entry's net/routes/additional")
    except ScenarioError as e:
        raise _err(source, f"{entry.where}.config" if entry.config else entry.where, str(e)) from None


def _locations(source: str, raw: list) -> list[str]:
    out = []
    for i, item in enumerate(raw):
        e = _check_keys(source, f"locations[{i}]", item, LOC_KEYS)
        if ("auto" in e) == ("center" in e):
            raise _err(source, f"locations[{i}]", "give either auto = N or center = [x, y]")
        if "auto" in e:
            if not 1 <= e["auto"] <= MAX_SCENARIOS:
                raise _err(source, f"locations[{i}].auto", f"must be in [1, {MAX_SCENARIOS}], got {e['auto']}")
            out += [f"auto:{k}" for k in range(e["auto"])]
        else:
            c = e["center"]
            if len(c) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in c):
                raise _err(source, f"locations[{i}].center", f"must be [x, y] in metres, got {c!r}")
            out.append(f"{float(c[0]):g},{float(c[1]):g}" + (f",{float(e['yaw']):g}" if "yaw" in e else ""))
    return out


def _density(source: str, key: str, v):
    """A density value: "auto", "model" or a finite number >= 0 (vehicles per km of car lane)."""
    if isinstance(v, str) and v.strip().lower() in ("auto", "model"):
        return v.strip().lower()
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise _err(source, key, f"values must be numbers >= 0 (vehicles per km of car lane), "
                   f"\"auto\" or \"model\", got {v!r}")
    return float(v)


def _vehicles(source: str, key: str, v) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 or v != int(v):
        raise _err(source, key, f"values must be whole numbers >= 0 (vehicles per window), got {v!r}")
    return int(v)


def _levels(source: str, data: dict) -> list[tuple]:
    """The traffic-level axis: (density, None) or (None, vehicles) per value; [(None, None)] without."""
    if "density" in data and "vehicles" in data:
        raise _err(source, "vehicles", "give either density or vehicles, not both")
    if "density" in data:
        return [(_density(source, "density", v), None) for v in data["density"]]
    if "vehicles" in data:
        return [(None, _vehicles(source, "vehicles", v)) for v in data["vehicles"]]
    return [(None, None)]


def _location_ok(loc) -> bool:
    if not isinstance(loc, str):
        return False
    if loc.startswith("auto:"):
        return loc[5:].isdigit()
    try:
        return len([float(v) for v in loc.split(",")]) in (2, 3)
    except ValueError:
        return False


def _token_sets(source: str, raw: list) -> dict[str, Any]:
    from ..tokens.file import TokenFileError, parse_tokens
    out: dict[str, Any] = {}
    for i, item in enumerate(raw):
        e = _check_keys(source, f"token_sets[{i}]", item, SET_KEYS)
        name = e.get("name", f"set{i}")
        body = {k: v for k, v in e.items() if k in ("frame", "p_mask", "agents")}
        variants = [(name, body)]
        if "vary" in e:  # {feature: [values]} for the first agent (the key vehicle)
            if not body.get("agents"):
                raise _err(source, f"token_sets[{i}].vary", "needs at least one agent to vary")
            for j, a in enumerate(body["agents"]):   # copied for each variant below
                if not isinstance(a, dict):
                    raise _err(source, f"token_sets[{i}].agents[{j}]", f"must be a table, got {a!r}")
            axes = list(e["vary"].items())
            for feat, values in axes:
                if not isinstance(values, list) or not values:
                    raise _err(source, f"token_sets[{i}].vary.{feat}", "must be a non-empty list")
            if math.prod(len(v) for _, v in axes) > MAX_SCENARIOS:
                raise _err(source, f"token_sets[{i}].vary", f"more than {MAX_SCENARIOS} variants")
            variants = []
            for combo in itertools.product(*[v for _, v in axes]):
                agents = [dict(a) for a in body["agents"]]
                agents[0].update({f: v for (f, _), v in zip(axes, combo)})
                label = ",".join(f"{f}={v:g}" if isinstance(v, (int, float)) else f"{f}={v}"
                                 for (f, _), v in zip(axes, combo))
                variants.append((f"{name}[{label}]", {**body, "agents": agents}))
        for vname, vbody in variants:
            if vname in out:
                raise _err(source, f"token_sets[{i}].name", f"{vname!r} is used twice")
            try:
                out[vname] = parse_tokens(vbody, f"{source}: token_sets[{i}]")
            except TokenFileError as ex:
                raise SpecError(str(ex)) from None
    return out


def parse_spec(data: dict, source: str, here: str = ".") -> Spec:
    names = GenerationConfig.settings()
    _check_keys(source, "", data, {**KEYS, **dict.fromkeys(names)})
    try:
        generation = GenerationConfig.from_mapping({k: v for k, v in data.items() if k in names}, source)
    except SettingError as e:
        raise SpecError(str(e)) from None
    for key in ("networks", "locations"):
        if key not in data and "scenarios" not in data:
            raise _err(source, key, "missing")
    nets = _networks(source, data.get("networks", []), here)
    locs = _locations(source, data.get("locations", []))
    sets = _token_sets(source, data.get("token_sets", [{"name": "none"}]))
    p_masks = data.get("p_mask", [None])
    for v in p_masks:
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 1):
            raise _err(source, "p_mask", f"values must be numbers in [0, 1], got {v!r}")
    seeds = data.get("seeds", [0])
    if isinstance(seeds, int) and not isinstance(seeds, bool) and seeds > MAX_SCENARIOS:
        raise _err(source, "seeds", f"a count must be <= {MAX_SCENARIOS}, got {seeds}")
    seeds = list(range(seeds)) if isinstance(seeds, int) else seeds
    if not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        raise _err(source, "seeds", f"must be integers (or a count), got {seeds!r}")
    levels = _levels(source, data)
    settings = {k: float(data.get(k, v)) for k, v in SWEEP_DEFAULTS.items()}
    if "step_length" in data:   # else the network's: SUMO's default with a demand (sim/sumo.py)
        settings["step_length"] = float(data["step_length"])
    for key, ok, rule in (("rollout", settings["rollout"] >= 0, ">= 0"),
                          ("step_length", settings.get("step_length", 1.0) > 0, "> 0"),
                          ("replay", 0 <= settings["replay"] <= 2, "in [0, 2]")):
        if not ok:
            raise _err(source, key, f"must be {rule}, got {settings[key]!r}")
    explicit = None
    if "scenarios" in data:
        explicit = []
        for i, e in enumerate(data["scenarios"]):
            e = dict(_check_keys(source, f"scenarios[{i}]", e, SCENARIO_KEYS))
            for key, pool in (("network", nets), ("token_set", sets)):
                e.setdefault(key, next(iter(pool), None))
                if e[key] not in pool:
                    raise _err(source, f"scenarios[{i}].{key}", f"{e[key]!r} is not defined "
                               f"(known: {', '.join(pool) or 'none'})")
            if not _location_ok(e.get("location")):
                raise _err(source, f"scenarios[{i}].location", f"must be 'auto:K' or 'X,Y' (or "
                           f"'X,Y,yaw'), got {e.get('location')!r}")
            e.setdefault("seed", 0)
            if "density" in e and "vehicles" in e:
                raise _err(source, f"scenarios[{i}].vehicles", "give either density or vehicles, not both")
            if "density" in e:
                e["density"] = _density(source, f"scenarios[{i}].density", e["density"])
            if "vehicles" in e:
                e["vehicles"] = _vehicles(source, f"scenarios[{i}].vehicles", e["vehicles"])
            explicit.append(e)
    digest = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]
    return Spec(source, data.get("name", os.path.splitext(os.path.basename(source))[0]), nets, locs,
                sets, p_masks, seeds, settings, generation, explicit, digest, levels)


def load_spec(path: str) -> Spec:
    from ..tokens.file import TokenFileError, _decode
    if not os.path.isfile(path):
        raise SpecError(f"{path}: no such file")
    with open(path, encoding="utf-8", errors="replace") as f:
        text = f.read()
    try:
        data = _decode(text, os.path.splitext(path)[1].lower(), path)
    except TokenFileError as e:
        raise SpecError(str(e)) from None
    if not isinstance(data, dict):
        raise SpecError(f"{path}: the spec must be a table/object at the top level")
    return parse_spec(data, path, os.path.dirname(os.path.abspath(path)))
