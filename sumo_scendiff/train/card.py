"""The weights card of a recipe's model: what made it, read from the run's own log (``OUT/recipe.json``).

    python -m sumo_scendiff.train card OUT          # prints it; the recipe also writes OUT/card.md

Which recipe and commit, the file's SHA-256, each stage's command in short and wall time, and the
data the stages read (windows and networks, from the recordings' manifests). Nothing in it is typed by
hand, so the card shipped beside ``weights/scendiff.pt`` says what the run did.
"""
from __future__ import annotations

import os

from .recipe import LOG, RecipeError

CARD = "card.md"
# the flags a stage's line is told by in the card (the rest is in recipe.json)
SHOWN = ("--steps", "--batch-size", "--lr", "--scenes", "--init-from", "--freeze-encoder", "--autoencoder",
         "--density", "--turned")


def _hms(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.0f} s"
    m = int(round(seconds / 60))
    return f"{m // 60} h {m % 60:02d} min" if m >= 60 else f"{m} min"


def _short(args: list[str], out: str) -> str:
    """A stage's program and the flags of :data:`SHOWN` with their values, paths relative to the run's
    directory."""
    words, i = [args[0]], 1
    while i < len(args):
        j = i + 1
        while j < len(args) and not args[j].startswith("--"):
            j += 1
        if args[i] in SHOWN:
            values = [os.path.relpath(v, out) if os.path.isabs(v) else v for v in args[i + 1:j]]
            words.append(" ".join([args[i], *values]))
        i = j
    return " ".join(words)


def _data(log: dict) -> str | None:
    from ..data.shards import DataError, read_manifest
    lines = []
    for split in ("train", "val"):
        try:
            m = read_manifest(os.path.join(log["data"], split))
        except (DataError, KeyError, TypeError):
            continue
        nets = sorted({n["name"] for n in m["nets"]})
        lines.append(f"{split}: {m['scenes']} windows of {len(nets)} networks ({', '.join(nets)})")
    return "; ".join(lines) or None


def _procs(n: int) -> str:
    return "one process" if n == 1 else f"{n} DDP processes"


def card(out: str) -> str:
    """The markdown card of the recipe run in ``out``. Raises RecipeError when it holds no finished run."""
    from ..core.files import read_json
    path = os.path.join(out, LOG)
    log = read_json(path, "recipe log", RecipeError) if os.path.exists(path) else {}
    if not log.get("model"):
        raise RecipeError(f"{out}: no finished recipe run (its {LOG} names no model)")
    stages = log.get("stages", {})
    scale = f" --scale {log['scale']}" if log.get("scale") else ""
    lines = [f"# `{os.path.basename(log['model']['path'])}`", "",
             f"Made by `python -m sumo_scendiff.train recipe {log['recipe']} OUT{scale}` at commit "
             f"`{log.get('commit') or 'unknown'}` ({_procs(log.get('procs', 1))} a training stage).", "",
             f"SHA-256 `{log['model']['sha256']}`.", "",
             "| stage | what it ran | wall time |", "|---|---|---|"]
    for name, entry in stages.items():
        state = "" if entry.get("done") else " (not finished)"
        lines.append(f"| {name} | `{_short(entry.get('args', ['?']), out)}` | {_hms(entry.get('seconds', 0.0))}{state} |")
    lines.append(f"| **all** | | **{_hms(sum(e.get('seconds', 0.0) for e in stages.values()))}** |")
    data = _data(log)
    if data:
        lines += ["", f"Data: {data}."]
    return "\n".join(lines) + "\n"
