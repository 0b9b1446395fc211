"""The inputs a scenario folder needs, inside it: a copied or zipped folder replays in stock SUMO.

Each input (network, route and additional files) is stored gzip-compressed under its own name in the
folder (SUMO reads ``.gz`` inputs). A file is compressed once per process and hard-linked into every
further folder on the same file system, so a run of many scenes costs the disk one copy. The files a
route or additional file reads (``<include href>``, a rerouter's or variable speed sign's ``file``, relative
to it) travel beside it as they are.
"""
from __future__ import annotations

import gzip
import os
import shutil
import tempfile

_cache: dict[tuple[str, float, int], str] = {}
_hrefs: dict[tuple[str, float, int], list[str]] = {}
_tmp: tempfile.TemporaryDirectory | None = None


def _compressed(src: str) -> str:
    """A gzip copy of ``src`` made once per process (``src`` itself when already compressed)."""
    global _tmp
    if src.endswith(".gz"):
        return src
    st = os.stat(src)
    key = (os.path.abspath(src), st.st_mtime, st.st_size)
    if key not in _cache or not os.path.exists(_cache[key]):
        if _tmp is None:
            _tmp = tempfile.TemporaryDirectory(prefix="scendiff-inputs-")
        out = os.path.join(_tmp.name, f"{len(_cache)}-{os.path.basename(src)}.gz")
        # mtime 0: the same input gives the same bytes, whenever it is bundled
        with open(src, "rb") as fi, open(out, "wb") as raw, \
                gzip.GzipFile(fileobj=raw, mode="wb", compresslevel=6, mtime=0) as fo:
            shutil.copyfileobj(fi, fo)
        _cache[key] = out
    return _cache[key]


def _key(src: str) -> tuple[str, float, int]:
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
            for el in ET.fromstring(data).iter():
                ref = el.get("href") if el.tag == "include" else \
                    el.get("file") if OUTPUTS.get(el.tag) != "file" else None
                refs += [ref] if ref else []
        _hrefs[key] = refs
    return _hrefs[key]


def _bundle_includes(src: str, folder: str) -> None:
    """The files ``src`` reads (:func:`_included`), copied under ``folder`` where its relative hrefs point from there (an
    absolute href points where it did; one leading out of the folder is left, the folder would not
    travel)."""
    from ..core.sumo_xml import include_path
    for href in _included(src):
        if os.path.isabs(href) or os.path.normpath(href).startswith(".."):
            continue
        target, dest = include_path(src, href), os.path.join(folder, href)
        if not os.path.isfile(target):
            continue                  # SUMO names the missing file when it loads the folder
        if not os.path.exists(dest):
            os.makedirs(os.path.dirname(dest), exist_ok=True)
            shutil.copyfile(target, dest)
        _bundle_includes(target, os.path.dirname(dest))


def bundle(src: str, folder: str, includes: bool = False) -> str:
    """Put ``src`` (compressed) into ``folder``; returns its name there (a file already in the
    folder stays as it is). ``includes``: and the files it includes (a route or additional file)."""
    if includes:
        _bundle_includes(src, folder)
    if os.path.dirname(os.path.abspath(src)) == os.path.abspath(folder):
        return os.path.basename(src)
    packed = _compressed(src)
    name = os.path.basename(src) + ("" if src.endswith(".gz") else ".gz")
    dest = os.path.join(folder, name)
    if not os.path.exists(dest):
        try:
            os.link(packed, dest)
        except OSError:       # another file system, or links not allowed
            shutil.copyfile(packed, dest)
    return name
