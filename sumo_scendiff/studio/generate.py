"""Generate through ``run``'s own code path, keep a scene as ``run`` wrote it.

A generation is ``run`` with ``--rollout 0`` into a draft folder under ``-o/.drafts``: the page's
window, token file, density, seed and guidance become ``run``'s flags (returned as the equivalent
command), so scene k is the one ``run`` writes with those flags, byte for byte. Keeping a scene
copies its folder to ``-o/NAME`` with the token file beside its files.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import re
import shlex
import shutil
import threading

from .geometry import StudioError
from .gui import gui_command
from .tokenfile import token_toml

MAX_SCENES = 8           # small multiples on one screen
_LOCK = threading.Lock()   # libsumo is one simulation per process: one generation at a time
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def _num(body: dict, key: str, lo: float, hi: float, default=None):
    v = body.get(key, default)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise StudioError(f"{key}: expected a number in [{lo:g}, {hi:g}], got {v!r}")
    return v


def flags(body: dict, tokens_path: str, out: str) -> list[str]:
    """``run``'s flags for a generate request (the window, the token file and the knobs)."""
    if not isinstance(body, dict):
        raise StudioError("expected a JSON object")
    args = []
    if body.get("ego"):
        if not isinstance(body["ego"], str):
            raise StudioError(f"ego: expected a vehicle id, got {body['ego']!r}")
        args += ["--ego", body["ego"]]
    else:
        c = body.get("center")
        if not (isinstance(c, list) and len(c) == 2):
            raise StudioError(f"center: expected [x, y] in network metres, got {c!r}")
        x, y = (_num({"center": v}, "center", -1e9, 1e9) for v in c)
        args += ["--center", f"{float(x)!r},{float(y)!r}"]
        yaw = _num(body, "yaw", -10.0, 10.0, 0.0)
        if yaw:   # a turned window: run's --yaw where run has it (run_flags names it where not)
            args += ["--yaw", repr(float(yaw))]
    density = body.get("density")
    if isinstance(density, str) and density in ("auto", "model"):
        args += ["--density", density]
    elif density is not None:
        args += ["--density", repr(float(_num(body, "density", 0.0, 1000.0)))]
    scenes = int(_num(body, "scenes", 1, MAX_SCENES, 1))
    seed = int(_num(body, "seed", 0, 2 ** 31 - 1, 0))
    args += ["--tokens", tokens_path, "--scenes", str(scenes), "--seed", str(seed)]
    g = _num(body, "guidance", 1.0, 20.0)
    if g is not None:
        args += ["--guidance", repr(float(g))]
    return args + ["--rollout", "0", "-o", out]


def run_flags(studio, args: list[str]) -> tuple[dict, list[str]]:
    """``run`` with the studio's network/scenario and ``args``: its summary and the lines it wrote
    on stderr (warnings). A problem ``run`` reports is a :class:`StudioError` with its line."""
    from .. import run
    from ..core.outputs import OutputError, claim
    from ..map.locations import LocationError
    from ..map.network import NetworkError
    from ..model.checkpoint import CheckpointError
    from ..sim.sumo import SimError
    from ..tokens.file import TokenFileError
    err = io.StringIO()
    with _LOCK, contextlib.redirect_stderr(err):
        try:
            o = run.get_options(studio.inputs + args)
            studio.hold_model()   # held by the server: run is handed its model (ScenarioGenerator.load)
            with claim(o.out):
                summary = run.run(o)
        except SystemExit:   # argparse: usage + one line
            line = err.getvalue().strip().splitlines()[-1]
            if "unrecognized arguments: --yaw" in line:
                line = "yaw: run places a --center window facing east (yaw 0); this run has no --yaw to turn it"
            raise StudioError(line) from None
        except (run.RunError, NetworkError, CheckpointError, SimError, TokenFileError, LocationError,
                FileExistsError, OutputError) as e:
            raise StudioError(str(e)) from None
    return summary, [ln for ln in err.getvalue().splitlines() if "warning" in ln]


def _scene(folder: str, row: dict) -> dict:
    """What the page draws of one scene folder: window, agents (box, -2..+2 s path, token, status)."""
    with open(os.path.join(folder, "scene.json")) as f:
        doc = json.load(f)
    agents = [{"x": a["x"], "y": a["y"], "heading": a["heading"], "length": a["length"], "width": a["width"],
               "speed": a.get("speed"), "vclass": a.get("vclass"), "vtype": a.get("vtype"),
               "status": a["status"], "reason": a.get("reason") or a.get("position_error"),
               "token": a.get("token"), "source": a.get("token_source"), "vehicle": a.get("vehicle"),
               "path": [[p["x"], p["y"]] for p in a.get("poses", [])]} for a in doc["agents"]]
    return {"scene": os.path.basename(folder), "window": doc["window"], "seed": doc["seed"],
            "p_mask": doc["p_mask"], "counts": doc["counts"], "agents": agents,
            "density_veh_per_km": row.get("density_veh_per_km"), "tokens_lost": row.get("user_tokens_lost", {})}


def generate(studio, body: dict) -> dict:
    """A generate request: a draft with the token file and ``run``'s scenes, for the page."""
    text = token_toml((body or {}).get("tokens") or {}) if isinstance(body, dict) else token_toml(None)
    draft = studio.new_draft()
    tokens_path = os.path.join(draft, "tokens.toml")
    out = os.path.join(draft, "scenes")
    args = flags(body, tokens_path, out)
    with open(tokens_path, "w") as f:
        f.write(text)
    summary, warnings = run_flags(studio, args)
    scenes = [_scene(os.path.join(out, r["scene"]), r) for r in summary["scenes"]]
    shown = [a if a not in (tokens_path, out) else {tokens_path: "tokens.toml", out: "OUT"}[a] for a in args]
    command = "python -m sumo_scendiff.run " + shlex.join(studio.inputs + shown)
    return {"draft": os.path.basename(draft), "command": command, "tokens": text, "warnings": warnings,
            "timing_s": summary["timing_s"], "scenes": scenes}


def keep(studio, body: dict) -> dict:
    """Copy a draft's scene to ``-o/NAME`` (never over an existing one), the token file beside its
    files; with ``openscenario`` also write it as OpenSCENARIO + OpenDRIVE as ``run --export`` does."""
    if not isinstance(body, dict):
        raise StudioError("expected a JSON object")
    draft, scene, name = body.get("draft"), body.get("scene"), body.get("name")
    if not (isinstance(draft, str) and NAME.fullmatch(draft)) or not isinstance(scene, str) or \
            not NAME.fullmatch(scene) or not (isinstance(name, str) and NAME.fullmatch(name)):
        raise StudioError("keep: expected draft, scene and name (letters, digits, _ . -)")
    src = os.path.join(studio.drafts, draft, "scenes", scene)
    if not os.path.isfile(os.path.join(src, "scene.json")):
        raise StudioError(f"keep: no scene {scene!r} in draft {draft!r}")
    target = os.path.join(studio.out, name)
    if os.path.exists(target):
        raise FileExistsError(f"{target}: exists (choose another name)")
    partial = f"{target}.partial-{os.getpid()}"
    shutil.copytree(src, partial)
    shutil.copy2(os.path.join(studio.drafts, draft, "tokens.toml"), os.path.join(partial, "tokens.toml"))
    os.replace(partial, target)
    exported = False
    if body.get("openscenario"):
        from ..export.batch import export_after
        from ..export.opendrive import ExportError
        try:
            with _LOCK, contextlib.redirect_stderr(io.StringIO()):
                export_after(studio.out, [name], "openscenario")
        except ExportError as e:
            raise StudioError(f"{target}: kept, but the OpenSCENARIO export failed: {e}") from None
        exported = True
    return {"name": name, "folder": os.path.abspath(target), "files": sorted(os.listdir(target)), "openscenario": exported,
            "sumo": gui_command(os.path.join(os.path.abspath(target), "scenario.sumocfg"))}
