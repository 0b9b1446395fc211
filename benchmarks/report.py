"""Shared by the benchmark scripts: print a markdown report and, with ``-o``, write it to a file."""
from __future__ import annotations

import os


def emit(text: str, output: str | None, title: str) -> None:
    print(text)
    if output:
        os.makedirs(os.path.dirname(os.path.abspath(output)), exist_ok=True)
        with open(output, "w") as f:
            f.write(f"# {title}\n\n{text}")
