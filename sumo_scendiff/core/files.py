"""File helpers every layer uses."""
from __future__ import annotations

import hashlib


def file_sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_png(path: str, img) -> None:
    """``img`` (an OpenCV BGR array) as a PNG file. Encoded in memory and written by Python, so a
    disk that refuses the write raises its OSError (cv2.imwrite only returns False)."""
    import cv2
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"{path}: the image cannot be encoded as PNG")
    with open(path, "wb") as f:
        f.write(buf.tobytes())
