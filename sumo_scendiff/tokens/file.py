"""Token files: the agent tokens and the global p_mask token a user asks a scene to contain.

Usage::

    python -m sumo_scendiff.run --tokens tokens.toml ...

    from sumo_scendiff.tokens.file import load_tokens
    spec = load_tokens("tokens.toml")            # or .json; raises TokenFileError
    agents = spec.for_window(window)             # list of feature dicts in the window frame
    tokens = agent_tokens_from_dicts(agents)     # (T, 170), see sumo_scendiff.tokens.encoding

A file is TOML (``.toml``) or JSON (``.json``) with the same structure (see docs/tokens.md)::

    frame = "window"    # or "world" (SUMO network coordinates, heading radians CCW from east)
    p_mask = 0.5        # optional; default 1.0 without agents, else 0.5
    [[agents]]
    x = 12.0
    y = -1.6
    speed = 8.0

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


class TokenFileError(ValueError):
    """Invalid token file; the one-line message starts with the file path."""


def _error(source: str, *parts: Any) -> TokenFileError:
    msg = ": ".join(str(p) for p in (source, *parts))
    return TokenFileError(msg.replace("\r", " ").replace("\n", " "))


def _is_number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


@dataclass(frozen=True)
class TokenSpec:
    """A parsed token file: frame, global p_mask and one feature dict per agent token."""

    frame: str
    p_mask: float
    agents: tuple[dict, ...]
    source: str

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


def load_tokens(path: str | Path) -> TokenSpec:
    """Read and check a ``.toml`` or ``.json`` token file."""
    source = str(path)
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise _error(source, f"unknown token file type {p.suffix or '(none)'!r} (expected .toml or .json)")
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
    p_mask = data.get("p_mask", 0.5 if agents else 1.0)
    if not _is_number(p_mask) or not 0.0 <= p_mask <= 1.0:
        raise _error(source, f"p_mask must be a number in [0, 1], got {p_mask!r}")
    return TokenSpec(frame=frame, p_mask=float(p_mask), agents=agents, source=source)


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
    if not agent:
        raise _error(source, where, f"no token features (give at least one of {', '.join(FEATURES)})")
    return agent
