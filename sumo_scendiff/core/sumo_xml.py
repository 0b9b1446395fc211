"""SUMO's XML inputs (route, additional and configuration files) read as SUMO reads them.

    for path, el in elements(["a.rou.xml", "b.add.xml.gz"], {"vehicle", "flow"}):
        t = seconds(el.get("depart"))

SUMO takes any root element (``<routes>``, ``<additional>``, ``<add>``, a ``<tlLogics>`` or a
``<viewsettings>`` given as an additional file) and acts on the elements it knows wherever they
are; a gzipped file whatever its name; and ``<include href="..."/>`` in place, the path relative
to the including file's folder (``GenericSAXHandler::startElement``). Files are streamed
(ElementTree iterparse) and each element is let go once it has been handed over, so a route file
of a whole day costs its reading time, not its size in memory. A file cut short (it ends inside
its root element) is read up to the cut, as SUMO reads a route file in steps and loads what comes
before (``MSRouteLoaderControl``): its whole elements are handed over, and the cut is told to who asks
(:class:`Cut`); SUMO quits when its reading reaches it, and refuses an additional file so cut at load.
A file pulled in by ``<include>`` and cut short is another matter for a route file: SUMO's reader of the
include reports the flaw as an error and hands back (``XMLSubSys::runParser``), so the including file
is read on past it and only the included file's rest is lost (``Cut.included_from``). So for any flaw
of an included file: missing ("Cannot read file"), empty, or not well-formed where it is (a mismatched
tag): SUMO reports it, keeps the elements whole before it and reads on past the include
(``Cut.problem``). SUMO refuses an additional file so flawed at load, which its own check
(sim.preflight) reports first.
"""
from __future__ import annotations

import gzip
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import BinaryIO, Collection, Iterable, Iterator
from xml.parsers import expat

_GZIP = b"\x1f\x8b"
# expat's errors at the end of input: the file ends inside an element, a tag or a character
_AT_END = frozenset({expat.errors.codes[c] for c in (expat.errors.XML_ERROR_NO_ELEMENTS,
                                                       expat.errors.XML_ERROR_UNCLOSED_TOKEN,
                                                       expat.errors.XML_ERROR_PARTIAL_CHAR)})
# the elements that repeat a vehicle, person or container (their begin defaults to the simulation's)
FLOWS = ("flow", "personFlow", "containerFlow")
# a calibrator's <flow>s are the vehicles it inserts to hold its edge's count, not demand of their own
NOT_DEMAND_PARENTS = ("calibrator",)
# the other names SUMO takes for its input and time options, in a configuration as on its command line
# (MSFrame: the one-letter abbreviations and addSynonyme's net, routes, additional); the long name is the
# one SUMO documents and writes when it saves a configuration
OPTION_SYNONYMS = {"n": "net-file", "net": "net-file", "r": "route-files", "routes": "route-files",
                   "a": "additional-files", "additional": "additional-files", "b": "begin", "e": "end"}


def option_name(name: str) -> str:
    """A SUMO option's long name, whichever of its names (OPTION_SYNONYMS) is given."""
    return OPTION_SYNONYMS.get(name, name)


class XmlError(ValueError):
    """One line: the file and what is wrong with it."""


@dataclass(frozen=True)
class Cut:
    """A file that ends inside its root element: where its reading stopped (line, 1-based; 0: it was
    not read); ``included_from``: the file whose ``<include>`` pulled it in (None: a file given to SUMO);
    ``problem``: an included file's other flaw SUMO reads past (None: cut short)."""
    path: str
    line: int
    included_from: str | None = None
    problem: str | None = None


def open_xml(path: str) -> BinaryIO:
    """``path`` opened for reading, gunzipped when it is gzipped (SUMO looks at the bytes, not at
    the name). Raises :class:`XmlError` for a missing or empty file."""
    if not os.path.isfile(path):
        raise XmlError(f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise XmlError(f"{path}: empty file")
    f = open(path, "rb")
    if f.read(2) == _GZIP:
        f.close()
        return gzip.open(path, "rb")
    f.seek(0)
    return f


def seconds(value: str | None) -> float | None:
    """A SUMO time (seconds, or clock time ``H:M:S`` / ``D:H:M:S``, as sumolib's ``parseTime``)
    in s; None for what is not one (``triggered``, ``now``, ``0:10``: SUMO takes no ``M:S``)."""
    from sumolib.miscutils import parseTime
    if value is None:
        return None
    try:
        t = float(parseTime(value.strip()))
    except (ValueError, TypeError, AttributeError):
        return None
    return None if math.isnan(t) else t


def boolean(value) -> bool:
    """A SUMO boolean attribute or option (``true``, ``1``, ``yes``, ``on``, ``x``, any case); anything
    else, or nothing, is false."""
    return str(value).strip().lower() in ("true", "1", "yes", "on", "x")


def include_path(including: str, href: str) -> str:
    """Where ``<include href>`` in ``including`` points, as SUMO resolves it."""
    return href if os.path.isabs(href) else os.path.normpath(os.path.join(os.path.dirname(including), href))


def elements(paths: Iterable[str], tags: Collection[str],
             cuts: list[Cut] | None = None) -> Iterator[tuple[str, ET.Element]]:
    """(file, element) for every element of ``paths`` whose tag is in ``tags`` and which lies in
    no other such element, with all it holds, in file order, includes in place. The element is
    emptied once the caller asks for the next one: keep what you need, not the element.
    A file cut short is read up to its cut (the module's doc), each such cut appended to ``cuts``.
    Raises :class:`XmlError` naming the file (and line) that cannot be read."""
    for path in paths:
        yield from _walk(os.path.abspath(path), frozenset(tags), (), cuts)


def _walk(path: str, tags: frozenset, chain: tuple[str, ...],
          cuts: list[Cut] | None) -> Iterator[tuple[str, ET.Element]]:
    if path in chain:
        raise XmlError(f"{chain[-1]}: includes {path}, which includes it back")
    try:
        f = open_xml(path)
    except XmlError as e:                      # no such file, empty
        if not chain:
            raise
        _read_past(cuts, Cut(path, 0, chain[-1], str(e).removeprefix(f"{path}: ")))
        return
    started: list = []
    with f:
        try:
            yield from _events(path, f, tags, chain, cuts, started)
        except ET.ParseError as e:
            cut_short = bool(started) and e.code in _AT_END
            if not (chain or cut_short):
                raise XmlError(f"{path}: not well-formed XML ({e})") from None
            _read_past(cuts, Cut(path, e.position[0], chain[-1] if chain else None,
                                 None if cut_short else f"not well-formed XML ({e})"))
        except (OSError, EOFError) as e:       # a gzip cut short or corrupt
            if not chain:
                raise XmlError(f"{path}: cannot be read ({e})") from None
            _read_past(cuts, Cut(path, 0, chain[-1], f"cannot be read ({e})"))


def _read_past(cuts: list[Cut] | None, cut: Cut) -> None:
    if cuts is not None:
        cuts.append(cut)


def _events(path: str, f: BinaryIO, tags: frozenset, chain: tuple[str, ...], cuts, started: list):
    """``started``: given the root element once it opens (a file cut before it is no XML at all)."""
    inside, depth, root = 0, 0, None
    for event, el in ET.iterparse(f, events=("start", "end")):
        if event == "start":
            depth += 1
            if root is None:
                root = el
                started.append(el)
            if inside:
                inside += 1
            elif el.tag in tags:
                inside = 1
            elif el.tag == "include" and el.get("href"):
                yield from _walk(include_path(path, el.get("href")), tags, chain + (path,), cuts)
            continue
        depth -= 1
        if inside:
            inside -= 1
            if inside == 0:
                yield path, el
        if not inside:
            el.clear()
            if depth == 1:
                root.clear()      # its children so far are done with: let them go


__all__ = ["FLOWS", "NOT_DEMAND_PARENTS", "Cut", "XmlError", "elements", "include_path", "open_xml", "seconds"]
