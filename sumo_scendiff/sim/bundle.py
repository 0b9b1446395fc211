"""The inputs a scenario folder needs, inside it: a copied or zipped folder replays in stock SUMO.

Each input (network, route and additional files) is stored gzip-compressed under its own name in the
folder (SUMO reads ``.gz`` inputs). A file is compressed once per process and hard-linked into every
further folder on the same file system, so a run of many scenes costs the disk one copy. The files a
route or additional file reads (``<include href>``, a rerouter's or variable speed sign's ``file``, relative
to it) travel beside it as they are. A flow without ``begin`` departs from the simulation's begin (SUMO's
``parseFlowAttributes``), and a vehicle's ``depart="begin"`` is the simulation's begin, which a
scene's configuration moves to the scene's time: the copy writes the begin SUMO gave them when the
demand was loaded, and nothing else of the file changes.
"""
from __future__ import annotations

import gzip
import io
import os
import re
import shutil
import tempfile
from xml.parsers import expat

_cache: dict[tuple, str] = {}
_hrefs: dict[tuple[str, float, int], list[str]] = {}
_beginless_at: dict[tuple[str, float, int], list[tuple[int, str]]] = {}
_tmp: tempfile.TemporaryDirectory | None = None
DEPARTING = ("vehicle", "trip", "person", "container")   # what departs at its ``depart``
_DEPART = re.compile(rb"""depart\s*=\s*(["'])begin\1""")


def _compressed(src: str, flow_begin: float | None = None) -> str:
    """A gzip copy of ``src`` made once per process (``src`` itself when already compressed and
    nothing is to change); ``flow_begin``: written into its flows without begin (:func:`_beginless`)."""
    global _tmp
    inserts = _beginless(src) if flow_begin is not None else []
    if src.endswith(".gz") and not inserts:
        return src
    key = _key(src) + ((flow_begin,) if inserts else ())
    if key not in _cache or not os.path.exists(_cache[key]):
        if _tmp is None:
            _tmp = tempfile.TemporaryDirectory(prefix="scendiff-inputs-")
        out = os.path.join(_tmp.name, f"{len(_cache)}-{os.path.basename(src).removesuffix('.gz')}.gz")
        # mtime 0: the same input gives the same bytes, whenever it is bundled
        with open(out, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", compresslevel=6, mtime=0) as fo:
            _copy(src, fo, inserts, flow_begin)
        _cache[key] = out
    return _cache[key]


def _beginless(src: str) -> list[tuple[int, str]]:
    """What a copy of ``src`` gives the begin SUMO loaded it with: each flow (vehicles, persons,
    containers; not a calibrator's) without ``begin`` (where its name ends, ``"begin"``: one is written
    there) and each vehicle, trip, person or container departing at ``"begin"`` (where its tag starts,
    ``"depart"``: the value is written in its place; a state loaded later would see it depart again at
    the new begin). Byte offsets in the file as read (gunzipped), read once per process."""
    from ..core.sumo_xml import FLOWS, NOT_DEMAND_PARENTS, open_xml
    key = _key(src)
    if key in _beginless_at:
        return _beginless_at[key]
    parser, found, stack = expat.ParserCreate(), [], []

    def start(name, attrs):
        if not (stack and stack[-1] in NOT_DEMAND_PARENTS):
            if name in FLOWS and "begin" not in attrs:
                found.append((parser.CurrentByteIndex + 1 + len(name), "begin"))
            elif name in DEPARTING and attrs.get("depart") == "begin":
                found.append((parser.CurrentByteIndex, "depart"))
        stack.append(name)
    parser.StartElementHandler, parser.EndElementHandler = start, lambda name: stack.pop()
    with open_xml(src) as f:
        try:
            parser.ParseFile(f)
        except expat.ExpatError:
            pass          # the flows up to a flaw: SUMO reads a route file cut short so far, and names any other
    _beginless_at[key] = found
    return found


def _copy(src: str, out, edits: list[tuple[int, str]], flow_begin: float | None) -> None:
    """``src`` (gunzipped) into the file object ``out``, with :func:`_beginless`'s ``edits`` made:
    `` begin="flow_begin"`` written into a flow, a ``depart="begin"`` given ``flow_begin``'s value."""
    from ..core.sumo_xml import open_xml
    value = repr(flow_begin).encode()
    done = 0
    with open_xml(src) as f:
        for at, kind in edits:
            out.write(f.read(at - done))
            done = at
            if kind == "begin":
                out.write(b' begin="' + value + b'"')
                continue
            tag = b""
            while not tag.endswith(b">"):   # the start tag (SUMO's files hold no ">" in a value)
                c = f.read(1)
                if not c:
                    break
                tag += c
            done += len(tag)
            out.write(_DEPART.sub(lambda m: b"depart=" + m.group(1) + value + m.group(1), tag, count=1))
        shutil.copyfileobj(f, out)


def _key(src: str) -> tuple:
    st = os.stat(src)
    return os.path.abspath(src), st.st_mtime, st.st_size


def _included(src: str) -> list[str]:
    """The files ``src`` reads, as written: its ``<include>``s' hrefs and the ``file`` of an element that
    is no output (a rerouter's or a variable speed sign's definitions), read once per process."""
    import xml.etree.ElementTree as ET

    from ..core.sumo_xml import open_xml
    from .additional import OUTPUTS
    key = _key(src)
    if key not in _hrefs:
        with open_xml(src) as f:
            data = f.read()
        refs = []
        if b"<include" in data or b" file=" in data:
            try:
                for _, el in ET.iterparse(io.BytesIO(data)):
                    ref = el.get("href") if el.tag == "include" else \
                        el.get("file") if OUTPUTS.get(el.tag) != "file" else None
                    refs += [ref] if ref else []
            except ET.ParseError:
                pass          # those up to a flaw: a route file cut short is SUMO's up to its cut
        _hrefs[key] = refs
    return _hrefs[key]


def _bundle_includes(src: str, folder: str, flow_begin: float | None = None) -> None:
    """The files ``src`` reads (:func:`_included`), copied under ``folder`` where its relative hrefs point from there (an
    absolute href points where it did; one leading out of the folder is left, the folder would not
    travel); ``flow_begin``: as :func:`bundle`'s."""
    from ..core.sumo_xml import include_path
    for href in _included(src):
        if os.path.isabs(href) or os.path.normpath(href).startswith(".."):
            continue
        target, dest = include_path(src, href), os.path.join(folder, href)
        if not os.path.isfile(target):
            continue                  # SUMO names the missing file when it loads the folder
        # an empty one too, and reads on past it (core.sumo_xml): copied as it is
        empty = not os.path.getsize(target)
        if not os.path.exists(dest):
            os.makedirs(os.path.dirname(dest), exist_ok=True)
            inserts = _beginless(target) if flow_begin is not None and not empty else []
            if inserts:
                with open(dest, "wb") as out:
                    _copy(target, out, inserts, flow_begin)
            else:
                shutil.copyfile(target, dest)
        if not empty:
            _bundle_includes(target, os.path.dirname(dest), flow_begin)


def bundle(src: str, folder: str, includes: bool = False, flow_begin: float | None = None) -> str:
    """Put ``src`` (compressed) into ``folder``; returns its name there (a file already in the
    folder stays as it is). ``includes``: and the files it includes (a route or additional file).
    ``flow_begin``: the begin SUMO gave the flows without one when the demand was loaded (the
    simulation's), written into the copies' such flows (the module's doc)."""
    if includes:
        _bundle_includes(src, folder, flow_begin)
    if os.path.dirname(os.path.abspath(src)) == os.path.abspath(folder):
        return os.path.basename(src)
    packed = _compressed(src, flow_begin)
    name = os.path.basename(src) + ("" if src.endswith(".gz") else ".gz")
    dest = os.path.join(folder, name)
    if not os.path.exists(dest):
        try:
            os.link(packed, dest)
        except OSError:       # another file system, or links not allowed
            shutil.copyfile(packed, dest)
    return name
