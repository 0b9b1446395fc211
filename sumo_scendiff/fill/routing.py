"""The demand's departures up to a time, each on the route SUMO would give it.

    departures, unrouted = routed_departures(net_path, route_files, additional, until=28800.0, since=21600.0)
    for dep in departures:
        dep.id, dep.type, dep.edges, dep.depart, dep.standing, dep.depart_pos

SUMO's own router (duarouter) reads the route files as SUMO does: trips between edges (through
their ``via`` edges), between junctions (``fromJunction``/``toJunction``, where the scenario sets
``junction-taz``, as SUMO refuses them otherwise) or the TAZs of the additional files; flows by period, rate, number or probability unfolded into
their vehicles (SUMO's ids, ``flow.k``); a vehicle on a ``routeDistribution`` given one of its
routes and one of a ``vTypeDistribution`` one of its types; scaled as the scenario's ``scale`` has SUMO
scale it (the copies ``id.1``, ...); each routed by free-flow time for its vehicle class. What it cannot route is left out, as SUMO would not drive it, and so is a vehicle
that departs on a trigger (``depart="triggered"``: when its person or container boards), whose
time no estimate without the simulation knows; both are counted as unrouted.
"""
from __future__ import annotations

import os
import re
import subprocess
import tempfile
from dataclasses import dataclass

from ..sim.scenario import SUMO_DEFAULT_SEED

# a trip's ends at junctions (SUMO and duarouter need junction-taz for them)
_JUNCTION_ATTRS = ("fromJunction", "toJunction", "viaJunctions")
# what SUMO refuses at loading and duarouter, told to ignore errors, only warns of
_UNKNOWN = re.compile(r"The (vehicle type|route|route distribution) '[^']*' for .* is not known")
# of the options on SUMO's random numbers (sim.scenario.own_random's words), those duarouter has
# (thread-rngs is the simulation's alone)
_ROUTER_RANDOM = frozenset({"--random"})
ROUTER_TIMEOUT_S = 600.0


class RoutingError(Exception):
    """duarouter could not read the demand (one line: its last message)."""


@dataclass(frozen=True)
class Departure:
    id: str
    type: str | None
    edges: tuple[str, ...]
    depart: float
    standing: bool                 # departs at speed 0 (SUMO's default departSpeed) and accelerates first
    depart_pos: str | None         # its departPos attribute
    stops: tuple[dict, ...] = ()   # its <stop> elements' attributes, in order (its route's first)


def routed_departures(net_path: str, route_files, additional=(), until: float = float("inf"),
                      since: float = float("-inf"), depart_speed: str | None = None,
                      junction_taz: bool = False, scale: str | None = None,
                      sumo_random: tuple[int, tuple[str, ...]] = (SUMO_DEFAULT_SEED, ())
                      ) -> tuple[list[Departure], int]:
    """Every vehicle of ``route_files`` and ``additional`` (SUMO loads an additional file's vehicles
    as demand) departing from ``since`` to ``until``, routed by duarouter,
    in the order of departure, and how many it found no route for. A vehicle without a
    ``departSpeed`` departs at ``depart_speed`` (SUMO's ``default.departspeed``: the scenario's, else
    the installed SUMO's); ``junction_taz``: the scenario's ``junction-taz`` (trips between
    junctions); ``scale``: its ``scale`` option (SUMO's copies of each vehicle, ``id.1``, ..., as duarouter
    makes them); ``sumo_random``: the seed and random-number options the user's SUMO runs the
    demand with (sim.scenario.own_random: seed, option words), which duarouter's random choices (probability flows,
    distributions) take too, so that another seed gives other routes. Raises :class:`RoutingError`."""
    from ..core.sumo_log import echo, first_error
    from ..core.tools import sumo_binary, sumo_defaults
    if depart_speed is None:
        depart_speed = sumo_defaults().get("default.departspeed", "0")
    traits = _traits([*route_files, *additional])   # an additional file's vehicles are demand too
    if not junction_taz:
        if traits.from_junction:
            raise RoutingError("trips from or to junctions (fromJunction/toJunction) need SUMO's junction-taz "
                               "option, which the scenario does not set (SUMO refuses them too)")
    with tempfile.TemporaryDirectory(prefix="scendiff-route-") as work:
        out = os.path.join(work, "routed.rou.xml")
        routes = _routes_for_router(route_files, traits.included_flaws, work)
        args = [sumo_binary("duarouter"), "-n", os.path.abspath(net_path),
                # duarouter routes an additional file's vehicles too, and refuses an empty -r
                *(["-r", ",".join(routes)] if routes else []), "-o", out,
                *(["--junction-taz"] if junction_taz else []), *(["--scale", scale] if scale else []),
                "--ignore-errors", "--no-step-log",
                # a public transport vehicle (one with a line) is left out of duarouter's output otherwise
                "--ptline-routing",
                # the files were judged by stock SUMO with the scenario's own options (sim/preflight.py);
                # duarouter's schema is stricter than sumo's (a flow's beginLane, SUMO's bicycle game)
                "--xml-validation", "never", "--xml-validation.routes", "never",
                "--seed", str(sumo_random[0]), *_router_random(sumo_random[1])]
        if until < float("inf"):
            args += ["--end", f"{until + 1.0:.3f}"]
        # duarouter 1.28 never returns from a probability flow that began before its --begin: with
        # one, the departures before ``since`` are routed too and left out here
        # (and from a --begin before 0 warns that there is no route input, routing them all the same)
        if since > 0 and not traits.probability_flow:
            args += ["--begin", f"{since:.3f}"]
        if additional:
            args += ["-a", ",".join(_for_router(additional, work))]
        try:
            done = subprocess.run(args, capture_output=True, text=True, timeout=ROUTER_TIMEOUT_S, cwd=work)
        except subprocess.TimeoutExpired:
            raise RoutingError(f"duarouter did not finish routing the demand in {ROUTER_TIMEOUT_S:g} s") from None
        if done.returncode != 0 or not os.path.exists(out):
            lines = (done.stderr or done.stdout).strip().splitlines() or [f"it ended (exit code {done.returncode}) "
                                                                          "without a message"]
            cause = first_error(done.stderr or done.stdout) or lines[-1]
            raise RoutingError(f"duarouter could not route the demand: {cause}")
        unknown = next((ln for ln in done.stderr.splitlines() if _UNKNOWN.search(ln)), None)
        if unknown:     # duarouter goes on with a default; SUMO refuses to load such a demand
            raise RoutingError(f"{unknown.removeprefix('Warning: ').rstrip('.')} (SUMO refuses such a demand)")
        # what it could not route, and why, each kind of warning once (a flaw repeated over a demand
        # would otherwise be thousands of lines)
        echo(done.stderr, prefix="duarouter: ", warnings_only=True)
        departures, triggered = _read(out, since, until, depart_speed, traits.repeats)
        return departures, triggered + sum("has no valid route" in line for line in done.stderr.splitlines())


def _router_random(words: tuple[str, ...]) -> list[str]:
    """Of own_random's option words (name, value pairs), those duarouter has."""
    return [w for name, value in zip(words[::2], words[1::2]) if name in _ROUTER_RANDOM for w in (name, value)]


# additional elements that are no demand and that duarouter 1.28 cannot read: a calibrator's <flow>
# (the vehicles it inserts to hold a count on its edge) ends duarouter without a word, and it refuses a
# rerouter's <interval> without begin (SUMO takes 0); routing the demand needs neither
_NOT_FOR_ROUTER = frozenset({"calibrator", "rerouter"})


def _for_router(additional, work: str) -> list[str]:
    """The additional files as duarouter is given them: each as it is, but a file holding elements of
    :data:`_NOT_FOR_ROUTER`, whose copy without them is written into ``work``."""
    import xml.etree.ElementTree as ET

    from ..core.sumo_xml import XmlError, elements, open_xml
    out = []
    for k, path in enumerate(os.path.abspath(p) for p in additional):
        try:
            # one in a file this one includes stays: the copy's includes would point elsewhere
            needless = any(f == path for f, _ in elements([path], _NOT_FOR_ROUTER))
        except XmlError:
            needless = False          # a broken file: duarouter names it in its own words
        if needless:
            with open_xml(path) as f:
                tree = ET.parse(f)
            for parent in list(tree.getroot().iter()):
                for el in [c for c in parent if c.tag in _NOT_FOR_ROUTER]:
                    parent.remove(el)
            path = os.path.join(work, f"{k}_{os.path.basename(path).removesuffix('.gz')}")
            tree.write(path)
        out.append(path)
    return out


def _routes_for_router(route_files, flawed: frozenset, work: str) -> list[str]:
    """The route files as duarouter is given them: each as it is where no file it includes is
    ``flawed`` (missing, empty, not well-formed or cut short: core.sumo_xml.Cut). SUMO reports such an
    included file, keeps its elements whole before the flaw and reads on past the include; duarouter
    quits on it. So a file with one below it is given as a copy in ``work`` of what SUMO reads of it
    (the user's files are never written); the fill has warned of the flaw (fill.api._begin)."""
    paths = [os.path.abspath(p) for p in route_files]
    if not flawed:
        return paths
    copies: dict[str, str | None] = {}
    return [_as_sumo_reads(p, flawed, work, copies) or p for p in paths]


def _as_sumo_reads(path: str, flawed: frozenset, work: str, copies: dict) -> str | None:
    """A copy in ``work`` of what SUMO reads of ``path``: its top-level elements whole before any flaw
    of its own (``path`` in ``flawed``), its includes pointing at such copies of theirs and those of
    a file SUMO reads nothing of left out; None where SUMO reads nothing of it."""
    import xml.etree.ElementTree as ET

    from ..core.sumo_xml import XmlError, open_xml
    if path in copies:
        return copies[path]
    copies[path] = None                        # an include back up the chain: SUMO refuses it at load
    out = os.path.join(work, f"r{len(copies)}_{os.path.basename(path).removesuffix('.gz')}")
    root, depth = None, 0
    try:
        f = open_xml(path)
    except XmlError:                           # missing, empty: nothing of it
        return None
    with f, open(out, "wb") as w:
        try:
            for event, el in ET.iterparse(f, events=("start", "end")):
                depth += 1 if event == "start" else -1
                if root is None:
                    root = el
                    w.write(f"<{el.tag}>\n".encode())
                elif event == "end" and depth == 1:
                    if _point_includes(el, path, flawed, work, copies):
                        w.write(ET.tostring(el, encoding="utf-8", xml_declaration=False) + b"\n")
                    root.clear()
        except (ET.ParseError, OSError, EOFError):
            pass                               # its flaw, or a cut SUMO also reads up to
        if root is not None:
            w.write(f"</{root.tag}>\n".encode())
    copies[path] = out if root is not None else None
    return copies[path]


def _point_includes(el, path: str, flawed: frozenset, work: str, copies: dict) -> bool:
    """Points the includes in ``el`` (a top-level element of ``path``) at what SUMO reads of theirs;
    False where ``el`` is an include of a file SUMO reads nothing of."""
    from ..core.sumo_xml import include_path
    for inc in [i for i in el.iter("include") if i.get("href")]:
        target = include_path(path, inc.get("href"))
        copy = _as_sumo_reads(target, flawed, work, copies)
        if copy is None and inc is el:
            return False
        inc.set("href", copy or target)
    return True


@dataclass(frozen=True)
class _Traits:
    from_junction: bool      # a trip or flow between junctions (fromJunction, toJunction, viaJunctions)
    probability_flow: bool   # a flow of random departures (duarouter hangs on one with --begin)
    repeats: dict            # routes driven more than once (``repeat``: a bus loop), edges -> repetitions
    included_flaws: frozenset = frozenset()   # included files SUMO reads past (core.sumo_xml.Cut)


def _traits(route_files) -> _Traits:
    """What of the demand changes how duarouter is run and its output read, in one pass over the
    files read as SUMO reads them (core.sumo_xml: includes, gzip, any root). duarouter's output
    writes a repeated route once, without the attribute."""
    from ..core.sumo_xml import XmlError, elements
    junction = probability = False
    repeats: dict[tuple[str, ...], int] = {}
    cuts: list = []
    try:
        for _, el in elements(route_files, ("vehicle", "trip", "flow", "route"), cuts):
            junction |= any(el.get(a) for a in _JUNCTION_ATTRS)
            probability |= el.tag == "flow" and el.get("probability") is not None
            for r in [el] if el.tag == "route" else el.findall("route"):
                if r.get("repeat") and r.get("edges"):
                    try:
                        repeats[tuple(r.get("edges").split())] = int(r.get("repeat"))
                    except ValueError:
                        continue      # SUMO names the bad value when it loads the file
    except XmlError:
        pass                          # a broken file: duarouter names it in its own words
    return _Traits(junction, probability, repeats, frozenset(c.path for c in cuts if c.included_from))


def _read(path: str, since: float, until: float, depart_speed: str = "0",
          repeats: dict[tuple[str, ...], int] | None = None) -> tuple[list[Departure], int]:
    """The departures of duarouter's output from ``since`` to ``until``, and how many depart on a
    trigger (no time); a route of ``repeats`` driven its times over."""
    from sumolib.xml import parse

    from ..core.sumo_xml import seconds
    named = {el.id: tuple(el.edges.split()) for el in parse(path, "route")
             if getattr(el, "id", None) and getattr(el, "edges", None)}
    out, triggered = [], 0
    for el in parse(path, "vehicle"):
        depart = seconds(el.depart)
        if depart is None:                  # "triggered", "containerTriggered", "split"
            triggered += 1
            continue
        if not since <= depart <= until:
            continue
        stops = []
        if el.hasChild("route"):
            route = el.getChild("route")[0]
            edges = tuple(route.edges.split())
            stops += route.getChild("stop") if route.hasChild("stop") else []
        else:
            edges = named.get(getattr(el, "route", None) or "", ())
        stops += el.getChild("stop") if el.hasChild("stop") else []
        edges = edges * (1 + (repeats or {}).get(edges, 0))
        if edges:
            out.append(Departure(el.id, getattr(el, "type", None), edges, depart,
                                 _departs_standing(getattr(el, "departSpeed", None) or depart_speed),
                                 getattr(el, "departPos", None),
                                 tuple(dict(s.getAttributes()) for s in stops)))
    out.sort(key=lambda d: d.depart)
    return out, triggered


def _departs_standing(v: str | None) -> bool:
    """Whether a vehicle with ``departSpeed`` ``v`` enters at speed 0 and accelerates first."""
    if v is None:
        return True
    try:
        return float(v) <= 0.0
    except ValueError:          # "max", "desired", "speedLimit", "avg" (the lane's), "last", "random": moving
        return False


__all__ = ["Departure", "RoutingError", "routed_departures"]
