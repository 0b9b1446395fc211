"""Demand for recording: the network's own route file, or random trips with a realistic vehicle mix.

Random demand uses SUMO's ``randomTrips.py`` (shipped by the ``eclipse-sumo`` wheel) with an insertion
density drawn per episode, so that recorded scenes range from nearly empty to congested, and a
``vTypeDistribution`` of cars of three sizes, vans, trucks, buses and motorcycles.
"""
from __future__ import annotations

import glob
import gzip
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from typing import Sequence

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


def write_vtypes(path: str) -> str:
    """Write the vehicle-type distribution ``mix`` as an additional file."""
    lines = ['<additional>', '    <vTypeDistribution id="mix">']
    for vid, vcls, shape, length, width, gap, acc, dec, vmax, p in VEHICLE_MIX:
        lines.append(f'        <vType id="{vid}" vClass="{vcls}" guiShape="{shape}" length="{length}" '
                     f'width="{width}" minGap="{gap}" accel="{acc}" decel="{dec}" maxSpeed="{vmax}" '
                     f'speedFactor="normc(1,0.1,0.2,2)" probability="{p}"/>')
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


_EDGE_ATTRS = re.compile(rb'\b(?:edges|from|to)\s*=\s*"([^"]*)"')
_DEPART = re.compile(rb'<(?:vehicle|trip|flow|person|personFlow)\b[^>]*?\b(?:depart|begin)\s*=\s*"([^"]*)"')
_FLOW_END = re.compile(rb'<(?:flow|personFlow)\b[^>]*?\bend\s*=\s*"([^"]*)"')
_FLOW = re.compile(rb'<(?:flow|personFlow)\b')
_DEMAND = re.compile(rb'<(?:vehicle|trip|flow|person|personFlow|container|containerFlow)\b')


def _read_xml(path: str, roots: tuple[bytes, ...]) -> bytes:
    if not os.path.exists(path):
        raise DemandError(f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise DemandError(f"{path}: empty file")
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rb") as f:
        data = f.read()
    root = next((r for r in roots if b"<" + r in data[:65536]), None)
    if root is None:
        names = " or ".join(f"<{r.decode()}>" for r in roots)
        raise DemandError(f"{path}: not a SUMO route file (no {names} element)")
    if not data.rstrip().endswith(b"</" + root + b">"):
        raise DemandError(f"{path}: truncated (no closing </{root.decode()}>)")
    return data


def _seconds(value: bytes) -> float | None:
    """A SUMO time attribute (seconds, or clock time ``[D:]HH:MM:SS``) in s; None for the
    non-times a depart may be (``triggered``, ``now``, ...)."""
    from sumolib.miscutils import parseTime
    try:
        return float(parseTime(value.decode()))
    except (ValueError, TypeError):
        return None


def check_demand(route_files: Sequence[str], edge_ids: set[str], additional: Sequence[str] = (),
                 sample: int = 2000) -> float:
    """Check route files as the set SUMO loads: each is a closed ``<routes>`` (or ``<additional>``)
    file, the set (with the additional files, which may hold vTypes or routes too) has vehicles,
    trips or flows, and the edges they use are the network's. A file of vTypes alone is legal.
    Returns the first departure (s). Raises :class:`DemandError` naming the file."""
    return demand_span(route_files, edge_ids, additional, sample)[0]


def demand_span(route_files: Sequence[str], edge_ids: set[str], additional: Sequence[str] = (),
                sample: int = 2000) -> tuple[float, float]:
    """:func:`check_demand`'s checks; returns the first and the last departure (s; a flow departs
    until its ``end``, one without an end or a file past its first 2 MB: ``inf``)."""
    data = {p: _read_xml(p, (b"routes", b"additional")) for p in route_files}
    data.update({p: _read_xml(p, (b"additional", b"routes")) for p in additional})
    if not any(_DEMAND.search(d) for d in data.values()):
        raise DemandError(f"{', '.join(route_files) or ', '.join(additional)}: no vehicle routes or "
                          "trips found")
    departs, ends, open_ended = [], [], False
    for path, d in data.items():
        used = []
        for m in _EDGE_ATTRS.finditer(d):
            used.extend(m.group(1).decode().split())
            if len(used) >= sample:
                break
        unknown = [e for e in used if e not in edge_ids]
        if len(unknown) > 0.01 * len(used):
            raise DemandError(f"{path}: does not match the network ({len(unknown)} of {len(used)} "
                              f"edges referenced are unknown, e.g. '{unknown[0]}')")
        head = min(len(d), 2_000_000)
        departs += [t for m in _DEPART.finditer(d, 0, head) for t in [_seconds(m.group(1))] if t is not None]
        ends += [t for m in _FLOW_END.finditer(d, 0, head) for t in [_seconds(m.group(1))] if t is not None]
        open_ended |= head < len(d) or len(_FLOW.findall(d, 0, head)) > len(_FLOW_END.findall(d, 0, head))
    if not departs:
        return 0.0, float("inf")
    return min(departs), float("inf") if open_ended else max(departs + ends)


def seeding_time(begin: float | None, config_begin: float | None, span: tuple[float, float],
                 route_files: Sequence[str], flag: str = "--begin") -> float:
    """The time to seed a demand's network at, on SUMO's clock: ``begin`` when given, else
    :data:`WARM_UP_S` after SUMO's start (the configuration's begin, not before the first departure)
    or the last departure if that comes sooner.
    Raises :class:`DemandError` when it lies outside the demand's departures (``span``, from
    :func:`demand_span`: before them the network is empty, after them it empties, and either would
    look like a filled network that is not) or before the configuration's begin (SUMO cannot go back)."""
    from ..core.cli import clock
    first, last = span
    start = first if config_begin is None else config_begin
    # a demand shorter than the warm-up is seeded at its last departure, when it has all its traffic
    t = min(max(start, first) + WARM_UP_S, max(last, start)) if begin is None else begin
    name = flag if begin is not None else f"the default start (first departure + {WARM_UP_S:g} s)"
    if t < first or t > last:
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
