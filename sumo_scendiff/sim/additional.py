"""A scenario's additional files and the outputs they name (detectors, edgeData, route probes, ...).

    sim_files = quiet_outputs(cfg.additional)       # for the product's own SUMO runs
    for sub in output_folders(path):                # beside an exported copy of ``path``
        os.makedirs(os.path.join(folder, sub), exist_ok=True)

An output element writes where its ``file`` says (a timed event where its ``dest`` says), relative
to its additional file. The product's own
SUMO runs (seeding, the lights at the start, the fill's probe) load the user's additional files, and
would write those outputs into the user's folder, over the results of the user's own runs: they load
a copy whose outputs go to SUMO's null device, and whose other relative paths (a rerouter's
definitions) point back at the original's folder; an ``<include>`` points at the included file, or
at its own quiet copy when it names outputs itself. An exported configuration loads the
file itself, and its folder gets the subfolders those outputs name: SUMO does not create a folder
for an output and refuses to start without it.
"""
from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET

# element -> its attribute naming an output file (SUMO's additional-file outputs)
OUTPUTS = {tag: "file" for tag in (
    "inductionLoop", "e1Detector", "instantInductionLoop", "laneAreaDetector", "e2Detector",
    "multiLaneAreaDetector", "entryExitDetector", "e3Detector", "edgeData", "laneData", "edgeRelation",
    "tazRelation", "routeProbe", "vTypeProbe")} | {"calibrator": "output", "timedEvent": "dest"}
# attributes that name an input file, relative to the additional file
INPUTS = ("file", "href")
NULL = "NUL"             # SUMO's name for the null device, on every platform

_cache: dict[tuple[str, float, int], str] = {}
_origin: dict[str, str] = {}          # quiet copy -> the user's file
_tmp: tempfile.TemporaryDirectory | None = None


def _read(path: str) -> ET.ElementTree | None:
    from ..core.sumo_xml import XmlError, open_xml
    try:
        with open_xml(path) as f:
            return ET.parse(f)
    except (ET.ParseError, XmlError, OSError, EOFError):
        return None         # SUMO names what is wrong with it when it loads it


def _outputs(tree: ET.ElementTree):
    for el in tree.iter():
        attr = OUTPUTS.get(el.tag) if isinstance(el.tag, str) else None
        if attr and el.get(attr):
            yield el, attr


def quiet_outputs(paths) -> tuple[str, ...]:
    """``paths`` with each additional file that names an output (itself or in a file it includes)
    replaced by a copy writing it nowhere (made once per process; the others as they are)."""
    return tuple(_quiet(os.path.abspath(p), ()) for p in paths)


def original(path: str) -> str:
    """The user's file a quiet copy was made of (``path`` itself if it is none), and in a text
    naming quiet copies (SUMO's message) each replaced by its original."""
    for copy, orig in _origin.items():
        path = path.replace(copy, orig)
    return path


def _quiet(path: str, chain: tuple[str, ...]) -> str:
    from ..core.sumo_xml import include_path
    try:
        st = os.stat(path)
    except OSError:
        return path                     # SUMO names the missing file
    key = (path, st.st_mtime, st.st_size)
    if key in _cache:
        return _cache[key]
    tree = _read(path) if path not in chain else None
    changed = False
    for el in tree.iter("include") if tree is not None else ():
        target = include_path(path, el.get("href") or "")
        quiet = _quiet(target, chain + (path,)) if el.get("href") else target
        changed |= quiet != target
        el.set("href", quiet)
    found = list(_outputs(tree)) if tree is not None else []
    if not found and not changed:
        _cache[key] = path
        return path
    here = os.path.dirname(path)
    for el in tree.iter():
        for attr in INPUTS:
            v = el.get(attr)
            if v and not os.path.isabs(v) and OUTPUTS.get(el.tag) != attr:
                el.set(attr, os.path.join(here, v))
    for el, attr in found:
        el.set(attr, NULL)
    _cache[key] = _write_copy(tree, path)
    return _cache[key]


def _write_copy(tree: ET.ElementTree, path: str) -> str:
    global _tmp
    if _tmp is None:
        _tmp = tempfile.TemporaryDirectory(prefix="scendiff-additional-")
    name = os.path.basename(path).removesuffix(".gz")
    copy = os.path.join(_tmp.name, f"{len(_origin)}-{name}")
    tree.write(copy, encoding="unicode")
    _origin[copy] = path
    return copy


def output_folders(path: str) -> list[str]:
    """The folders, relative to ``path``'s own and inside it, its outputs write into."""
    tree = _read(path)
    found = set()
    for el, attr in _outputs(tree) if tree is not None else ():
        sub = os.path.dirname(os.path.normpath(el.get(attr)))
        if sub and not os.path.isabs(sub) and not sub.startswith(".."):
            found.add(sub)
    return sorted(found)


__all__ = ["NULL", "OUTPUTS", "original", "output_folders", "quiet_outputs"]
