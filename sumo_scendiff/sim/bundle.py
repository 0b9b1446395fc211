"""The inputs a scenario folder needs, inside it: a copied or zipped folder replays in stock SUMO.

Each input (network, route and additional files) is stored gzip-compressed under its own name in the
folder (SUMO reads ``.gz`` inputs). A file is compressed once per process and hard-linked into every
further folder on the same file system, so a run of many scenes costs the disk one copy.
"""
from __future__ import annotations

import gzip
import os
import shutil
import tempfile

_cache: dict[tuple[str, float, int], str] = {}
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


def bundle(src: str, folder: str) -> str:
    """Put ``src`` (compressed) into ``folder``; returns its name there (a file already in the
    folder stays as it is)."""
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
