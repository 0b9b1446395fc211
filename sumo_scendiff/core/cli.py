"""What every command-line module shares: help that reads as plain text and shows its defaults."""
from __future__ import annotations

import argparse
import re
import sys

_ROLES = re.compile(r":(?:mod|func|class|meth|attr|data):`(~?)([\w.]+)`")


def plain(text: str) -> str:
    """reST markup of a docstring as plain text: ``x`` -> x, :mod:`~a.b` -> b, :mod:`a.b` -> a.b."""
    text = _ROLES.sub(lambda m: m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2), text)
    return text.replace("``", "")


def description(doc: str) -> str:
    """The docstring's first paragraph (the description)."""
    return plain(doc.split("\n\n")[0])


def epilog(doc: str) -> str:
    """The docstring after its first paragraph (examples and details), as plain text."""
    return plain(doc.split("\n\n", 1)[1]) if "\n\n" in doc else ""


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Examples kept as written; a flag's default shown where its help does not already say it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "default" in text.lower() or action.default in (None, False, True, argparse.SUPPRESS) \
                or not action.option_strings:
            return text
        return f"{text} (default: %(default)s)" if text else "(default: %(default)s)"


_NEGATIVE = re.compile(r"-\.?\d")


def joined(parser: argparse.ArgumentParser, args=None) -> list[str]:
    """The command line with the value of every coordinate flag (its metavar a list such as
    ``X0,Y0,X1,Y1``) that begins with a minus joined to its flag, ``--area -100,-50,300,350`` ->
    ``--area=-100,-50,300,350``: argparse would take such a value for a flag of its own (networks
    with negative coordinates are common). Give it to ``parser.parse_args``."""
    args = list(sys.argv[1:] if args is None else args)
    flags = {s for a in parser._actions if "," in str(a.metavar or "") for s in a.option_strings}
    out, k = [], 0
    while k < len(args):
        if args[k] in flags and k + 1 < len(args) and _NEGATIVE.match(args[k + 1]):
            out.append(f"{args[k]}={args[k + 1]}")
            k += 2
        else:
            out.append(args[k])
            k += 1
    return out


def sumo_time(value: str) -> float:
    """An argparse type: a time as SUMO reads one, seconds or clock time ``[[D:]H:]M:S``
    (:func:`~sumo_scendiff.core.sumo_xml.seconds`, as the route files' times are read), at or after 0."""
    from .sumo_xml import seconds
    t = seconds(value)
    if t is None:
        raise argparse.ArgumentTypeError(f"not a time in seconds or H:M:S: {value!r}")
    if not 0 <= t < float("inf"):
        raise argparse.ArgumentTypeError(f"a time must be >= 0 seconds, got {value!r}")
    return t


def clock(seconds: float) -> str:
    """``seconds`` as SUMO's human-readable time, ``H:MM:SS`` (``D:HH:MM:SS`` past a day)."""
    s = int(round(seconds))
    d, s = divmod(s, 86400)
    h, s = divmod(s, 3600)
    m, s = divmod(s, 60)
    return f"{d}:{h:02d}:{m:02d}:{s:02d}" if d else f"{h}:{m:02d}:{s:02d}"
