"""File helpers every layer uses."""
from __future__ import annotations

import errno
import gzip
import hashlib
import json
import os
import zlib
from xml.etree.ElementTree import ParseError, iterparse

# free space under which a file another program left incomplete is taken for a full disk
FULL_BYTES = 1 << 20


def cache_dir(kind: str) -> str:
    """The project's cache folder for ``kind`` (``$XDG_CACHE_HOME`` or ~/.cache, then
    sumo-scendiff/KIND): never beside a user's file, which may be read-only or shared."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "sumo-scendiff", kind)


def file_sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_json(path: str, what: str = "JSON", error: type[Exception] = ValueError):
    """The JSON document in ``path``; a file that cannot be opened or decoded raises ``error`` with
    one line naming it: ``PATH: unreadable WHAT (why)``."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise error(f"{path}: unreadable {what} ({e})") from None


def write_png(path: str, img) -> None:
    """``img`` (an OpenCV BGR array) as a PNG file. Encoded in memory and written by Python, so a
    disk that refuses the write raises its OSError (cv2.imwrite only returns False)."""
    import cv2
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"{path}: the image cannot be encoded as PNG")
    with open(path, "wb") as f:
        f.write(buf.tobytes())


def check_whole(path: str) -> str:
    """``path``, written by another program (SUMO's saved state, duarouter's routes), read to its end:
    those programs do not all fail when the disk refuses a write, and leave the file cut short. Raises
    OSError (ENOSPC where the file system is full, else EIO) naming the file if it is incomplete."""
    try:
        with (gzip.open(path) if path.endswith(".gz") else open(path, "rb")) as f:
            for _ in iterparse(f):
                pass
    except (EOFError, zlib.error, gzip.BadGzipFile, ParseError):
        st = os.statvfs(os.path.dirname(os.path.abspath(path)))
        full = st.f_bavail * st.f_frsize < FULL_BYTES
        raise OSError(errno.ENOSPC if full else errno.EIO,
                      os.strerror(errno.ENOSPC) if full else "written incomplete", path) from None
    return path
