"""Token files: the agent tokens and the global p_mask token a user asks a scene to contain.

Usage::

    python -m sumo_scendiff.run --tokens tokens.toml ...

    from sumo_scendiff.tokens.file import load_tokens
    spec = load_tokens("tokens.toml")            # or .json; raises TokenFileError
    agents = spec.for_window(window)             # list of feature dicts in the window frame
                                                 # (network references stay: generation resolves them)
    tokens = agent_tokens_from_dicts(agents)     # (T, 170), see sumo_scendiff.tokens.encoding

A file is TOML (``.toml``) or JSON (``.json``) with the same structure (see docs/tokens.md)::

    frame = "window"    # or "world" (SUMO network coordinates, heading radians CCW from east)
    p_mask = 0.5        # optional; default 1.0 without agents, else 0.5
    [[agents]]
    x = 12.0
    y = -1.6
    speed = 8.0
    [[agents]]          # a user's terms: places on the road, vehicle classes, manoeuvres
    ahead = 15.0        # or edge = "E1", lane = 0, pos = 30 (resolved at generation)
    lane_offset = 1
    vclass = "truck"    # or vtype = "bus_articulated": one of the scenario's own vTypes
    manoeuvre = "stop"

Every error is a :class:`TokenFileError` with a one-line message that starts with the file path.
"""
from __future__ import annotations

import json
import math
import numbers
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

FRAMES = ("window", "world")
TOP_KEYS = ("frame", "p_mask", "agents")

# places on the road, resolved on the network at generation (generation/token_resolve.py)
REFERENCE_KEYS = ("ahead", "lane_offset", "edge", "lane", "pos")
# vehicle classes by name: data/demand.py VEHICLE_MIX's sizes (tests/test_tokenfile.py holds them
# equal; data/ is a room this one may not import), with core.scene.VEHICLE_CLASSES' names and aliases
VCLASS_SIZES = {"passenger": (4.6, 1.8), "car": (4.6, 1.8), "delivery": (6.0, 2.1), "van": (6.0, 2.1),
                "truck": (10.5, 2.5), "bus": (12.0, 2.55), "motorcycle": (2.2, 0.9)}
# the aliases' names among core.scene.VEHICLE_CLASSES (a token's class is its vehicle's, sim/seeding.py)
VCLASS_NAMES = {"car": "passenger", "van": "delivery"}
# manoeuvres in the token's own features. A turn's 0.4 rad chord turns the heading by 0.8 rad over
# the 2 s, about what a car turning at a junction does in its first 2 s; inside the model's
# [-0.7, 0.7] heading_to_final range (tokens/encoding.py: CCW positive = left)
TURN = 0.4
MANOEUVRES = {"stop": ("final_speed", 0.0), "turn_left": ("heading_to_final", TURN),
              "turn_right": ("heading_to_final", -TURN), "straight": ("heading_to_final", 0.0)}
USER_KEYS = REFERENCE_KEYS + ("vclass", "manoeuvre", "vtype")


class TokenFileError(ValueError):
    """Invalid token file; the one-line message starts with the file path."""


def _error(source: str, *parts: Any) -> TokenFileError:
    msg = ": ".join(str(p) for p in (source, *parts))
    return TokenFileError(msg.replace("\r", " ").replace("\n", " "))


def _is_number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def default_p_mask(tokens) -> float:
    """The global p_mask token where nobody gives one: 1.0 (the model draws the whole scene) for a
    window without agent tokens, else 0.5 (docs/tokens.md)."""
    return 0.5 if len(tokens) else 1.0


@dataclass(frozen=True)
class TokenSpec:
    """A parsed token file: frame, global p_mask and one feature dict per agent token."""

    frame: str
    p_mask: float
    agents: tuple[dict, ...]
    source: str
    p_mask_given: bool = True    # False: p_mask is the default for the file's own agents

    def asked_p_mask(self) -> float | None:
        """The file's ``p_mask`` where it gives one; None lets a window's own tokens decide
        (:func:`default_p_mask`: the vehicles already there count too)."""
        return self.p_mask if self.p_mask_given else None

    def for_window(self, window) -> list[dict]:
        """Agent dicts in the frame of ``window`` (a :class:`~sumo_scendiff.core.geometry.Window`).

        World-frame x/y and heading are converted; speeds, extents and heading_to_final (relative
        to the agent's own heading) are unchanged. Raises :class:`TokenFileError` if a position
        lies outside the window (|x| or |y| > window.size / 2).
        """
        half = 0.5 * float(window.size)
        out = []
        for i, agent in enumerate(self.agents):
            a = dict(agent)
            if self.frame == "world":
                a = _world_to_window(a, window)
            if "x" in a and max(abs(a["x"]), abs(a["y"])) > half:
                where = (f"world position ({agent['x']:g}, {agent['y']:g}) is "
                         if self.frame == "world" else "position is ")
                raise _error(self.source, f"agents[{i}]", f"{where}({a['x']:.2f}, {a['y']:.2f}) m "
                             f"in the window frame, outside the window [-{half:g}, {half:g}] m")
            out.append(a)
        return out


def _world_to_window(agent: dict, window) -> dict:
    a = dict(agent)
    if "x" in a:
        sx, sy = window.world_to_scene(np.array([a["x"], a["y"]]))
        a["x"], a["y"] = float(sx), float(sy)
    if "heading" in a:
        a["heading"] = float(window.yaw_to_scene(a["heading"]))
    return a


def load_tokens(path: str | Path, net=None) -> TokenSpec:
    """Read and check a ``.toml`` or ``.json`` token file, or an OpenSCENARIO ``.xosc`` whose Init
    gives world-frame tokens (tokens/xosc.py; positions checked to lie on ``net`` when given)."""
    source = str(path)
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".xosc":
        from .xosc import XoscError, xosc_tokens
        try:
            return parse_tokens(xosc_tokens(source, net), source)
        except XoscError as e:
            raise TokenFileError(str(e)) from None
    if suffix not in (".toml", ".json"):
        raise _error(source, f"unknown token file type {p.suffix or '(none)'!r} (expected .toml, .json or .xosc)")
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise _error(source, "no such file") from None
    except IsADirectoryError:
        raise _error(source, "is a directory, not a token file") from None
    except UnicodeDecodeError:
        raise _error(source, "not valid UTF-8 text") from None
    except OSError as e:
        raise _error(source, f"cannot read ({e.strerror or e})") from None
    return parse_tokens(_decode(text, suffix, source), source)


def _decode(text: str, suffix: str, source: str) -> Any:
    if suffix == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as e:
            raise _error(source, f"not valid JSON ({e})") from None
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        raise _error(source, "reading TOML needs Python >= 3.11; use a .json file") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise _error(source, f"not valid TOML ({e})") from None


def parse_tokens(data: Mapping[str, Any], source: str) -> TokenSpec:
    """Check an already decoded token table (e.g. one embedded in a sweep spec)."""
    if not isinstance(data, Mapping):
        raise _error(source, f"top level must be a table, got {type(data).__name__}")
    for key in data:
        if key not in TOP_KEYS:
            raise _error(source, f"unknown key {key!r} (expected {', '.join(TOP_KEYS)})")
    frame = data.get("frame", "window")
    if frame not in FRAMES:
        raise _error(source, f'frame must be "window" or "world", got {frame!r}')
    agents = _parse_agents(data.get("agents", []), frame, source)
    p_mask = data.get("p_mask", default_p_mask(agents))
    if not _is_number(p_mask) or not 0.0 <= p_mask <= 1.0:
        raise _error(source, f"p_mask must be a number in [0, 1], got {p_mask!r}")
    return TokenSpec(frame=frame, p_mask=float(p_mask), agents=agents, source=source,
                     p_mask_given="p_mask" in data)


def _parse_agents(raw: Any, frame: str, source: str) -> tuple[dict, ...]:
    if not isinstance(raw, list):
        raise _error(source, "'agents' must be a list of tables")
    agents = []
    for i, item in enumerate(raw):
        if not isinstance(item, Mapping):
            raise _error(source, "'agents' must be a list of tables", f"agents[{i}] is {item!r}")
        agents.append(_parse_agent(item, frame, source, f"agents[{i}]"))
    return tuple(agents)


def _parse_agent(item: Mapping[str, Any], frame: str, source: str, where: str) -> dict:
    from .encoding import (  # torch: import lazily
        FEATURES,
        TokenError,
        validate_token_features,
    )

    given = {k: v for k, v in item.items() if v is not None}  # JSON null = feature absent
    user = {k: given.pop(k) for k in USER_KEYS if k in given}
    given.update(_user_features(user, given, source, where))
    for k, v in given.items():
        if isinstance(v, (list, tuple, Mapping)):
            raise _error(source, where, f"token feature {k!r} must be a single number, got {v!r}")
    check = dict(given)
    if frame == "world":  # world x, y are not window metres: check them here, validate stand-ins
        for k in ("x", "y"):
            if k in given:
                if not _is_number(given[k]) or not math.isfinite(given[k]):
                    raise _error(source, where, f"token feature {k!r} must be a finite number "
                                 f"(world metres), got {given[k]!r}")
                check[k] = 0.0
    try:
        valid = validate_token_features(check)
    except TokenError as e:
        raise _error(source, where, e) from None
    agent = {k: float(given[k]) for k in FEATURES if k in valid and np.isfinite(valid[k][0])}
    agent.update(_references(user, given, source, where))
    agent.update(_vtype(user, source, where))
    if "vclass" in user:    # checked by _user_features; the vehicle is of that class, whatever box the model draws
        agent["vclass"] = VCLASS_NAMES.get(user["vclass"], user["vclass"])
    if not agent:
        raise _error(source, where, f"no token features (give at least one of {', '.join(FEATURES)})")
    return agent


def _user_features(user: dict, given: Mapping, source: str, where: str) -> dict:
    """The features ``vclass`` and ``manoeuvre`` stand for; a name not known, or a feature also
    given directly, is an error naming the key."""
    out = {}
    if "vclass" in user:
        name = user["vclass"]
        if not isinstance(name, str) or name not in VCLASS_SIZES:
            raise _error(source, where, f"vclass: unknown vehicle class {name!r} "
                         f"(expected {', '.join(VCLASS_SIZES)})")
        for k in ("length", "width"):
            if k in given:
                raise _error(source, where, f"vclass: conflicts with {k!r} (give a class or a size)")
        out["length"], out["width"] = VCLASS_SIZES[name]
    if "manoeuvre" in user:
        name = user["manoeuvre"]
        if not isinstance(name, str) or name not in MANOEUVRES:
            raise _error(source, where, f"manoeuvre: unknown manoeuvre {name!r} "
                         f"(expected {', '.join(MANOEUVRES)})")
        feature, value = MANOEUVRES[name]
        if feature in given:
            raise _error(source, where, f"manoeuvre: {name!r} conflicts with {feature!r}")
        out[feature] = value
    return out


def _vtype(user: dict, source: str, where: str) -> dict:
    """The scenario's vType a token names (checked against the scenario where it is known,
    sim/fleet.py); it says the class and, unless the token gives one, the size: not with ``vclass``."""
    if "vtype" not in user:
        return {}
    name = user["vtype"]
    if not isinstance(name, str) or not name.strip():
        raise _error(source, where, f"vtype: must be the id of one of the scenario's vTypes (a string), got {name!r}")
    if "vclass" in user:
        raise _error(source, where, "vtype: conflicts with 'vclass' (a vType has its class)")
    return {"vtype": name}


def _references(user: dict, given: Mapping, source: str, where: str) -> dict:
    """The checked places on the road (:data:`REFERENCE_KEYS`), as they stay until generation."""
    ref = {k: user[k] for k in REFERENCE_KEYS if k in user}
    if not ref:
        return {}
    lane_form, ahead_form = [k for k in ("edge", "lane", "pos") if k in ref], [k for k in ("ahead", "lane_offset") if k in ref]
    if lane_form and ahead_form:
        raise _error(source, where, f"{lane_form[0]}: conflicts with {ahead_form[0]!r} "
                     f"(place the vehicle by edge/lane/pos or by ahead/lane_offset)")
    for k in ("x", "y"):
        if k in given:
            raise _error(source, where, f"{next(iter(ref))}: conflicts with {k!r} (give a position once)")
    if lane_form:
        for k in ("edge", "pos"):
            if k not in ref:
                raise _error(source, where, f"{k}: missing (edge and pos place a vehicle on a lane; lane defaults to 0)")
        if not isinstance(ref["edge"], str) or not ref["edge"]:
            raise _error(source, where, f"edge: must be an edge id (a string), got {ref['edge']!r}")
        if not _is_number(ref["pos"]) or not math.isfinite(ref["pos"]) or ref["pos"] < 0:
            raise _error(source, where, f"pos: must be metres >= 0 along the lane, got {ref['pos']!r}")
        lane = ref.get("lane", 0)
        if not _is_integer(lane) or lane < 0:
            raise _error(source, where, f"lane: must be a lane index >= 0, got {lane!r}")
        return {"edge": ref["edge"], "lane": int(lane), "pos": float(ref["pos"])}
    ahead, offset = ref.get("ahead", 0.0), ref.get("lane_offset", 0)
    if not _is_number(ahead) or not math.isfinite(ahead) or abs(ahead) > 50.0:
        raise _error(source, where, f"ahead: must be metres in [-50, 50] along the window's axis, got {ahead!r}")
    if not _is_integer(offset):
        raise _error(source, where, f"lane_offset: must be a whole number of lanes (+ left, - right), got {offset!r}")
    return {"ahead": float(ahead), "lane_offset": int(offset)}


def _is_integer(v: Any) -> bool:
    return _is_number(v) and math.isfinite(v) and float(v) == int(v)
