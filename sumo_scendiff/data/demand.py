"""Demand for recording: the network's own route file, or random trips with a realistic vehicle mix.

Random demand uses SUMO's ``randomTrips.py`` (shipped by the ``eclipse-sumo`` wheel) with an insertion
density drawn per episode, so that recorded scenes range from nearly empty to congested, and a
``vTypeDistribution`` of cars of three sizes, vans, trucks, buses and motorcycles.
"""
from __future__ import annotations

import glob
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from typing import Sequence

from ..core.sumo_xml import FLOWS, NOT_DEMAND_PARENTS, Cut, XmlError, elements, seconds
from ..core.tools import sumo_tool

# (id, vClass, guiShape, length, width, minGap, accel, decel, maxSpeed, probability)
VEHICLE_MIX = (
    ("car_small", "passenger", "passenger/hatchback", 3.9, 1.70, 2.0, 2.9, 4.5, 50.0, 0.25),
    ("car", "passenger", "passenger", 4.6, 1.80, 2.5, 2.6, 4.5, 50.0, 0.35),
    ("car_large", "passenger", "passenger/van", 5.1, 1.95, 2.5, 2.4, 4.5, 45.0, 0.15),
    ("van", "delivery", "delivery", 6.0, 2.10, 2.5, 2.0, 4.0, 38.0, 0.09),
    ("truck", "truck", "truck", 10.5, 2.50, 3.0, 1.3, 4.0, 25.0, 0.06),
    ("bus", "bus", "bus", 12.0, 2.55, 3.0, 1.2, 4.0, 25.0, 0.03),
    ("motorcycle", "motorcycle", "motorcycle", 2.2, 0.90, 1.5, 4.0, 7.0, 45.0, 0.07),
)


WARM_UP_S = 600.0   # s of demand SUMO runs before seeding when no time is given


class DemandError(ValueError):
    """A demand file that cannot be used with its network; the message names the file."""


@dataclass(frozen=True)
class RandomDemand:
    insertion_density: float    # vehicles per hour per km of lane
    end: float                  # seconds of departures
    seed: int
    fringe_factor: float = 5.0


def write_vtypes(path: str, default_share: float = 0.0) -> str:
    """Write the vehicle-type distribution ``mix`` as an additional file. ``default_share`` of each
    vehicle class's vehicles take SUMO's own vType of that class instead (one naming only its
    vClass: SUMO's defaults for it, e.g. a passenger car of 5 m x 1.8 m, as scenarios that define no
    vType of their own drive); the classes' shares stay those of :data:`VEHICLE_MIX`."""
    if not 0.0 <= default_share <= 1.0:
        raise ValueError(f"the share of SUMO's default vehicle types must lie in [0, 1], not {default_share:g}")
    lines = ['<additional>', '    <vTypeDistribution id="mix">']
    for vid, vcls, shape, length, width, gap, acc, dec, vmax, p in VEHICLE_MIX:
        p = p * (1.0 - default_share) if default_share else p   # (without: the file as before)
        lines.append(f'        <vType id="{vid}" vClass="{vcls}" guiShape="{shape}" length="{length}" '
                     f'width="{width}" minGap="{gap}" accel="{acc}" decel="{dec}" maxSpeed="{vmax}" '
                     f'speedFactor="normc(1,0.1,0.2,2)" probability="{p:.6g}"/>')
    if default_share:
        classes: dict[str, float] = {}
        for m in VEHICLE_MIX:
            classes[m[1]] = classes.get(m[1], 0.0) + m[9]
        lines += [f'        <vType id="sumo_{vcls}" vClass="{vcls}" probability="{p * default_share:.6g}"/>'
                  for vcls, p in classes.items()]
    lines += ['    </vTypeDistribution>', '</additional>', '']
    with open(path, "w") as f:
        f.write("\n".join(lines))
    return path


def random_trips(net_path: str, out_path: str, spec: RandomDemand) -> str:
    """Write trips of type ``mix`` for ``net_path`` with randomTrips.py; returns ``out_path``."""
    tool = sumo_tool("randomTrips.py")
    cmd = [sys.executable, tool, "-n", net_path, "-o", out_path, "-b", "0", "-e", f"{spec.end:g}",
           "--insertion-density", f"{spec.insertion_density:.3f}", "--seed", str(spec.seed),
           "--fringe-factor", f"{spec.fringe_factor:g}", "--edge-permission", "passenger",
           "--min-distance", "100", "--random-departpos", "--prefix", "r",
           "--trip-attributes", 'type="mix" departLane="best" departSpeed="max"',
           "--no-validate"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0 or not os.path.exists(out_path):
        tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or ["unknown error"]
        raise DemandError(f"{net_path}: randomTrips failed ({tail[0]})")
    return out_path


DEMAND = ("vehicle", "trip", "flow", "person", "personFlow", "container", "containerFlow")
_PER_HOUR = ("vehsPerHour", "personsPerHour", "containersPerHour", "perHour")
_EDGE_ATTRS = ("edges", "from", "to", "via")
DAY_S = 86400.0        # a flow with neither an end nor a simulation end departs for a day (SUMO's)
READ_LIMIT = 100_000   # demand elements of one file read for its departures; past them: open-ended


def flow_span(el, begin: float | None = None, end: float | None = None) -> tuple[float, float] | None:
    """The first and the last departure (s) of a ``flow``/``personFlow``/``containerFlow`` element
    as SUMO computes them (``SUMOVehicleParserHelper::parseFlowAttributes``): ``begin`` defaults to
    the simulation's begin, the flow runs to its ``end``, or for ``number`` vehicles at a ``period``
    / per-hour rate, else to the simulation's ``end`` or for a day; None for a triggered one."""
    b = seconds(el.get("begin")) if el.get("begin") is not None else (begin or 0.0)
    if b is None:
        return None
    if el.get("end") is not None:
        e = seconds(el.get("end"))
        return None if e is None else (b, e)
    rate = next((float(el.get(a)) for a in _PER_HOUR if _number(el.get(a))), None)
    offset = _period(el.get("period")) if el.get("period") is not None else 3600.0 / rate if rate else None
    number = _number(el.get("number"))
    if number and offset is not None:
        return b, b + (number - 1) * offset
    return b, end if end is not None and end > b else b + DAY_S


def _period(value: str) -> float | None:
    """A flow's period in s: a time, or ``exp(r)`` (departures at random, ``r`` a second: on
    average every 1/r s)."""
    if value.startswith("exp(") and value.endswith(")"):
        r = _number(value[4:-1])
        return 1.0 / r if r else None
    return seconds(value)


def _number(value: str | None) -> float | None:
    try:
        return float(value) if value is not None and float(value) > 0 else None
    except ValueError:
        return None


def departures(el, begin: float | None = None, end: float | None = None) -> tuple[float, float] | None:
    """The first and last departure (s) of one demand element (:data:`DEMAND`); None when it
    departs on a trigger (``triggered``, ``containerTriggered``, ``split``)."""
    if el.tag in FLOWS:
        return flow_span(el, begin, end)
    depart = el.get("depart")
    t = (begin or 0.0) if depart == "begin" else seconds(depart)
    return None if t is None else (t, t)


def _edges_used(el):
    for sub in el.iter():
        for a in _EDGE_ATTRS:
            value = sub.get(a)
            if value:
                yield from value.split()


def check_demand(route_files: Sequence[str], edge_ids: set[str], additional: Sequence[str] = (),
                 sample: int = 2000) -> float:
    """Check route files as the set SUMO loads: each file is XML SUMO reads (any root element,
    gzipped or not, includes in place), the set (with the additional files, which may hold vTypes
    or routes too) has vehicles, trips, flows, persons or containers, and the edges they use are
    the network's. A file of vTypes alone is legal. Returns the first departure (s).
    Raises :class:`DemandError` naming the file."""
    return demand_span(route_files, edge_ids, additional, sample)[0]


def route_steps_of(options) -> dict:
    """A scenario's own --route-steps (how far ahead SUMO reads its route files; ``options``: its
    (name, value) pairs) as :func:`demand_span` takes it: ``{}`` for SUMO's default."""
    from ..core.sumo_xml import seconds
    given = seconds(dict(options).get("route-steps"))
    return {} if given is None else {"route_steps": given}


def demand_files(route_files: Sequence[str], additional: Sequence[str] = ()) -> list[str]:
    """The files that hold a scenario's demand: its route files, and the additional files with
    vehicles, trips, flows, persons or containers in them (SUMO loads those as demand too: a game's
    or a scenario's traffic often lives in an .add.xml)."""
    return list(route_files) + [p for p in additional if _holds_demand(p)]


def _holds_demand(path: str) -> bool:
    try:
        return any(el.tag in DEMAND for _, el in elements([path], DEMAND + NOT_DEMAND_PARENTS))
    except XmlError:   # SUMO's preflight has judged the file; unreadable here is no demand
        return False


def write_without_demand(path: str, folder: str) -> str:
    """A copy of the additional file ``path`` in ``folder`` without its vehicles, trips, flows, persons
    and containers (those of a file it includes too), the rest as it is (vTypes, routes, stops,
    detectors, programs), its relative input paths pointing at the original's folder: what SUMO loads
    of it but its demand. Returns the copy's path."""
    import xml.etree.ElementTree as ET

    from ..core.sumo_xml import include_path, open_xml
    from ..sim.additional import INPUTS, OUTPUTS
    path = os.path.abspath(path)
    with open_xml(path) as f:
        tree = ET.parse(f)
    for parent in [el for el in tree.iter() if el.tag not in NOT_DEMAND_PARENTS]:
        for el in [c for c in parent if c.tag in DEMAND]:
            parent.remove(el)
    for el in tree.iter():
        for attr in INPUTS:
            v = el.get(attr)
            if not v or OUTPUTS.get(el.tag) == attr:
                continue
            target = include_path(path, v)
            el.set(attr, write_without_demand(target, folder) if el.tag == "include" and _holds_demand(target)
                   else target)
    fd, copy = tempfile.mkstemp(suffix="-" + os.path.basename(path).removesuffix(".gz"), dir=folder)
    with os.fdopen(fd, "w") as f:
        tree.write(f, encoding="unicode")
    return copy


ROUTE_STEPS_S = 200.0  # SUMO's --route-steps: how far ahead of its clock it reads a route file


@dataclass(frozen=True)
class CutDemand:
    """A route file cut short (core.sumo_xml.Cut) as SUMO runs it: it loads the file's departures up to
    the cut and quits when its reading reaches the cut, ``route_steps`` ahead of its clock. A file cut short
    that another one includes (``included_from``) is reported and read past: SUMO does not quit (``stop``
    is infinite), it leaves out the included file's rest."""
    path: str
    line: int
    read_to: float      # the last whole departure before the cut (s; a flow's: its begin)
    stop: float         # SUMO's time when its reading reaches the cut (s; inf: it reads on)
    ahead: float        # how far ahead of its clock SUMO reads (s; its --route-steps)
    included_from: str | None = None
    problem: str | None = None     # an included file's flaw other than a cut (core.sumo_xml.Cut)

    def warning(self) -> str:
        from ..core.cli import clock
        if self.included_from is not None:
            flaw = (self.problem or f"cut short at line {self.line} (no closing tag)")
            kept = (f"reads it to its last whole departure, {self.read_to:g} s ({clock(self.read_to)}), "
                    if self.line else "")
            return (f"{self.path}: {flaw}, included from {self.included_from}; SUMO reports an error, "
                    f"{kept}and reads on past its include")
        return (f"{self.path}: cut short at line {self.line} (no closing tag); SUMO reads it to its last whole "
                f"departure, {self.read_to:g} s ({clock(self.read_to)}), and quits when its reading, "
                f"{self.ahead:g} s ahead of its clock (--route-steps), reaches the cut: at about {self.stop:g} s "
                f"({clock(self.stop)})")


class Span(tuple):
    """(first, last) departure of a demand; ``cut``: its earliest route file cut short, or None."""
    cut: CutDemand | None = None


def demand_span(route_files: Sequence[str], edge_ids: set[str], additional: Sequence[str] = (),
                sample: int = 2000, begin: float | None = None, end: float | None = None,
                route_steps: float = ROUTE_STEPS_S) -> Span:
    """:func:`check_demand`'s checks; returns the first and the last departure (s) of the set (a
    flow departs until its end, :func:`flow_span`; ``begin`` and ``end`` are the simulation's,
    a flow's defaults). A file with more than :data:`READ_LIMIT` demand elements leaves the last
    departure open (``inf``). A route file cut short is read up to its cut, as SUMO reads it
    (``route_steps``: the scenario's --route-steps), and named in the span's ``cut``."""
    first, last, found, cuts = float("inf"), float("-inf"), False, []
    for path in list(route_files) + list(additional):
        span, n, cut = _file_span(path, edge_ids, sample, begin, end, route_steps)
        found |= n > 0
        cuts += [cut] if cut else []
        if span:
            first, last = min(first, span[0]), max(last, span[1])
    if not found:
        raise DemandError(f"{', '.join(route_files) or ', '.join(additional)}: no vehicle routes or "
                          "trips found")
    out = Span((0.0, float("inf")) if first == float("inf") else (first, last))
    out.cut = min(cuts, key=lambda c: c.stop) if cuts else None
    return out


def _file_span(path: str, edge_ids: set[str], sample: int, begin, end,
               route_steps: float = ROUTE_STEPS_S) -> tuple[tuple[float, float] | None, int, CutDemand | None]:
    """One file's (first, last) departure (None: none with a time), its number of demand elements
    read, and its cut (a file cut short); checks the first ``sample`` edges it names against the network."""
    first, last, n, used, unknown, cuts, read_to = float("inf"), float("-inf"), 0, 0, [], [], {}
    try:
        for where, el in elements([path], DEMAND + ("route", "routeDistribution"), cuts):
            if used < sample:
                names = list(_edges_used(el))
                used += len(names)
                unknown += [(e, where) for e in names if e not in edge_ids]
            if el.tag not in DEMAND:
                continue
            n += 1
            span = departures(el, begin, end)
            if span:
                first, last = min(first, span[0]), max(last, span[1])
                read_to[where] = max(read_to.get(where, span[0]), span[0])   # per file: an included one's cut
            if n >= READ_LIMIT:
                last = float("inf")
                break
    except XmlError as e:
        raise DemandError(str(e)) from None
    if len(unknown) > 0.01 * used:
        raise DemandError(f"{unknown[0][1]}: does not match the network ({len(unknown)} of {used} "
                          f"edges referenced are unknown, e.g. '{unknown[0][0]}')")
    return (None if first == float("inf") else (first, last)), n, _cut(cuts, read_to, begin, route_steps)


def _cut(cuts: list[Cut], read_to: dict[str, float], begin: float | None, route_steps: float) -> CutDemand | None:
    """The cut SUMO quits on, as SUMO meets it: SUMO reads ``route_steps`` ahead of its clock (at
    once, at its begin, when it is not positive); else the first cut of an included file, which SUMO
    reports and reads past. ``read_to``: each file's last departure read (s)."""
    if not cuts:
        return None
    cut = next((c for c in cuts if c.included_from is None), cuts[0])
    if cut.included_from is not None:
        return CutDemand(cut.path, cut.line, read_to.get(cut.path, begin or 0.0), float("inf"), route_steps,
                         cut.included_from, cut.problem)
    last = max([begin or 0.0, *read_to.values()])
    stop = last - route_steps if route_steps > 0 else (begin or 0.0)
    return CutDemand(cut.path, cut.line, last, max(stop, begin or 0.0), route_steps)


def start_times(scen, edge_ids: set[str], begin: float | None, demand: Sequence[str], flag: str = "--begin",
                seed: bool = True) -> tuple[float, float | None, Span]:
    """How the product runs a scenario's demand (``scen``: a sim.scenario.SumoScenario; ``demand``: the
    files holding it, :func:`demand_files`), as run, the fill and sweeps take it: (the time SUMO starts
    at: the configuration's begin, else SUMO's own default 0, as stock ``sumo -c`` starts: actuated
    lights start their program at SUMO's begin, so a later start holds other traffic at T even where
    the network is empty before the first departure; the seeding time the demand is run
    to, :func:`seeding_time` of ``begin`` (None when ``seed`` is False: the caller decides); the demand's
    span, with a route file cut short in ``span.cut``). Raises :class:`DemandError`."""
    span = demand_span(list(scen.routes), edge_ids, scen.additional, begin=scen.begin, end=scen.end,
                       **route_steps_of(scen.options))
    at = seeding_time(begin, scen.begin, span, list(demand), flag=flag, config_end=scen.end) if seed else None
    return (scen.begin if scen.begin is not None else 0.0), at, span


def seeding_time(begin: float | None, config_begin: float | None, span: tuple[float, float],
                 route_files: Sequence[str], flag: str = "--begin", config_end: float | None = None) -> float:
    """The time to seed a demand's network at, on SUMO's clock: ``begin`` when given, else
    :data:`WARM_UP_S` after SUMO's start (the configuration's begin, not before the first departure)
    or the last departure if that comes sooner.
    Raises :class:`DemandError` when it lies before the demand's first departure (``span``, from
    :func:`demand_span`: the network is empty and would look like a filled network that is not),
    when the default start lies after its last, before the configuration's begin (SUMO cannot go
    back), after its end (SUMO stops before) or after SUMO quits on a route file cut short
    (``span.cut``, :func:`demand_span`; the default start moves before). A ``begin`` given after the last departure is
    SUMO's as any other: its vehicles may still drive (long trips, rerouters sending them round)."""
    from ..core.cli import clock
    first, last = span
    start = first if config_begin is None else config_begin
    # a demand shorter than the warm-up is seeded at its last departure, when it has all its traffic
    t = min(max(start, first) + WARM_UP_S, max(last, start)) if begin is None else begin
    cut = getattr(span, "cut", None)
    if cut is not None and begin is None:   # the default start before SUMO quits on a route file cut short
        t = max(min(t, cut.stop), start)
    name = flag if begin is not None else f"the default start (first departure + {WARM_UP_S:g} s)"
    if cut is not None and t > cut.stop:
        raise DemandError(f"{name} {t:g} s ({clock(t)}) lies after SUMO quits: {cut.warning()}; give an "
                          f"earlier {flag}")
    if config_end is not None and t > config_end:
        raise DemandError(f"{name} {t:g} s ({clock(t)}) lies after the configuration's end "
                          f"{config_end:g} s ({clock(config_end)}); give an earlier {flag}")
    if t < first or (t > last and begin is None):
        when = f"departures from {first:g} s ({clock(first)})" + \
            ("" if last == float("inf") else f" to {last:g} s ({clock(last)})")
        raise DemandError(f"{name} {t:g} s ({clock(t)}) lies outside the demand ({', '.join(route_files)}: "
                          f"{when}); give a {flag} within it")
    if t < start:
        raise DemandError(f"{name} {t:g} s ({clock(t)}) lies before the configuration's begin "
                          f"{start:g} s ({clock(start)}); give a later {flag}")
    return t


def check_routes(routes_path: str, edge_ids: set[str], sample: int = 2000) -> float:
    """:func:`check_demand` of one route file, which must hold vehicles itself."""
    return check_demand([routes_path], edge_ids, sample=sample)


def find_demand(net) -> str | None:
    """The largest ``*.rou.xml`` beside the network that matches it, or None (random trips)."""
    edges = {ln.edge for ln in net.lanes}
    found = []
    for path in glob.glob(os.path.join(os.path.dirname(os.path.abspath(net.path)), "*.rou.xml")):
        try:
            check_routes(path, edges)
        except DemandError:
            continue
        found.append((os.path.getsize(path), path))
    return max(found)[1] if found else None
