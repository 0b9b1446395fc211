"""Shared by the benchmark scripts: a markdown report printed and, with ``-o``, written to a file."""
from __future__ import annotations

import os


def emit(text: str, output: str | None, title: str) -> None:
    print(text)
    if output:
        os.makedirs(os.path.dirname(os.path.abspath(output)), exist_ok=True)
        with open(output, "w") as f:
            f.write(f"# {title}\n\n{text}")

