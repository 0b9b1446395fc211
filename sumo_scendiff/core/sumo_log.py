"""SUMO's and duarouter's messages, each kind once: repeated warnings summarised in one line.

    for line in summarise(stderr_text.splitlines()):
        print(line, file=sys.stderr)
    # Warning: No connection between edge '…' and edge '…' found. (1 475 times, first: No connection
    #   between edge 'a' and edge 'b' found.)

A scenario with a flaw repeated over its demand (a route through a removed connection, a type
without a class) makes SUMO and duarouter print the same warning for every vehicle: thousands of
lines that hide the one line that matters. Messages are grouped by their *shape* (the message with
its quoted names and its numbers replaced), in the order each shape first appeared; a shape seen
once is printed as it is, a repeated one once with its count and its first instance.
"""
from __future__ import annotations

import os
import re
import sys
from collections import Counter
from contextlib import contextmanager

# what varies between instances of one message: quoted names (ids of edges, vehicles, lanes) and
# numbers (times, positions, counts), SUMO's own wording around them stays
_QUOTED = re.compile(r"'[^']*'|\"[^\"]*\"")
_NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?!\w)")
_PREFIX = re.compile(r"^(Warning|Error|Message):\s*")


def shape(line: str) -> str:
    """The message ``line`` with its quoted names as '…' and its numbers as #."""
    return _NUMBER.sub("#", _QUOTED.sub("'…'", line.strip()))


def thousands(n: int) -> str:
    """A count as SUMO users read it in this project's docs (1 475)."""
    return f"{n:,}".replace(",", " ")


def summarise(lines) -> list[str]:
    """``lines`` (SUMO's or duarouter's console output) with each repeated message shape once:
    ``<shape> (N times, first: <first instance>)``; blank lines dropped, order of first appearance."""
    counts, first = Counter(), {}
    for line in lines:
        text = line.rstrip("\n")
        if not text.strip():
            continue
        key = shape(text)
        counts[key] += 1
        first.setdefault(key, text)
    out = []
    for key, n in counts.items():
        if n == 1:
            out.append(first[key])
        else:
            example = _PREFIX.sub("", first[key].strip())
            out.append(f"{key} ({thousands(n)} times, first: {example})")
    return out


def echo(text: str, stream=None, prefix: str = "", warnings_only: bool = False) -> None:
    """Write SUMO's console output ``text`` to ``stream`` (default stderr) summarised, each line
    after ``prefix`` (a tool's name); ``warnings_only``: its warnings, not its other messages."""
    stream = stream or sys.stderr
    lines = [ln for ln in text.splitlines() if not warnings_only or ln.startswith("Warning:")]
    for line in summarise(lines):
        stream.write(prefix + line + "\n")


def first_error(text: str) -> str | None:
    """SUMO's first error in its console output ``text`` (its cause; "Quitting (on error)." comes
    last), without the ``Error:`` prefix; None if it wrote none."""
    line = next((ln for ln in text.splitlines() if ln.startswith("Error:")), None)
    return line.removeprefix("Error:").strip() if line is not None else None


@contextmanager
def caught_stderr():
    """What the process writes to its stderr (file descriptor 2: libsumo's SUMO writes there, past
    Python) while the block runs, kept from the terminal; yields a function that returns it.
    Python's own ``sys.stderr`` (progress bars, messages) still reaches the terminal."""
    import tempfile
    with tempfile.TemporaryFile(mode="w+", errors="replace") as caught:
        sys.stderr.flush()
        saved = os.dup(2)
        python = sys.stderr if _is_fd2(sys.stderr) else None
        if python is not None:
            sys.stderr = os.fdopen(os.dup(saved), "w", buffering=1, errors="replace")
        os.dup2(caught.fileno(), 2)

        def text() -> str:
            caught.flush()
            caught.seek(0)
            return caught.read()
        try:
            yield text
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            if python is not None:
                sys.stderr.close()
                sys.stderr = python


def _is_fd2(stream) -> bool:
    try:
        return stream.fileno() == 2
    except (AttributeError, OSError, ValueError):   # a test's capture, a StringIO
        return False


__all__ = ["caught_stderr", "echo", "first_error", "shape", "summarise", "thousands"]
