"""The page's tokens as a token file (docs/tokens.md), checked by the project's own reader."""
from __future__ import annotations

import json
import math
import tomllib

from ..tokens.file import TokenFileError, parse_tokens
from .geometry import StudioError

# what the panel can set, in the order the file lists them; the reader checks the values
KEYS = ("edge", "lane", "pos", "heading", "vclass", "vtype", "length", "width", "speed", "final_speed",
        "manoeuvre", "heading_to_final")


def _value(key: str, v) -> str:
    if isinstance(v, str):
        return json.dumps(v)   # a JSON string is a TOML basic string
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise StudioError(f"token {key}: expected a number or a name, got {v!r}")
    return str(int(v)) if key == "lane" else repr(float(v))


def token_toml(body: dict) -> str:
    """``{"p_mask": p, "agents": [{key: value}]}`` -> the TOML text ``run --tokens`` reads; a
    :class:`StudioError` naming the token and key if the project's reader refuses it."""
    if not isinstance(body, dict):
        raise StudioError("tokens: expected an object with p_mask and agents")
    agents = body.get("agents") or []
    if not isinstance(agents, list) or not all(isinstance(a, dict) for a in agents):
        raise StudioError("tokens: agents must be a list of objects")
    lines = ["# written by the scenario studio (python -m sumo_scendiff.studio); docs/tokens.md"]
    if body.get("p_mask") is not None:
        lines.append(f"p_mask = {_value('p_mask', body['p_mask'])}")
    for k, a in enumerate(agents):
        unknown = sorted(set(a) - set(KEYS))
        if unknown:
            raise StudioError(f"token {k}: unknown key {unknown[0]!r} (expected {', '.join(KEYS)})")
        lines += ["", "[[agents]]"] + [f"{key} = {_value(key, a[key])}" for key in KEYS if a.get(key) is not None]
    text = "\n".join(lines) + "\n"
    try:
        parse_tokens(tomllib.loads(text), "tokens.toml")
    except TokenFileError as e:
        raise StudioError(str(e)) from None
    return text
