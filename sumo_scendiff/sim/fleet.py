"""The scenario's own fleet: which of its vTypes each seeded vehicle is (docs/tokens.md, "vType").

    fleet = Fleet.read(sim, exclude="sd")          # its vTypes as SUMO has them, and their mix
    chosen = fleet.assign(scene, others, net, named, rng)   # per agent a vType id, or None
    fleet.token_vtypes(tokens, source)             # a token's ``vtype``: known, and its size

A scenario with a demand brings its own vehicles: their classes, sizes, driving parameters and
emission classes (its vTypes, in route and additional files, some in vTypeDistributions). A generated
agent becomes a vehicle of one of those types rather than of the model's training fleet. The mix is
the share of each vType among the demand's vehicles: those in the simulation when the seeding starts,
else those the route files depart (a distribution's vehicles by its probabilities). Only what the
model draws counts: road motor vehicles (bicycles, trams, trains and people are not).

Each scene's agents get a fleet drawn from the mix (as many types as agents, the seeded RNG), and
each drawn type goes to the agent it fits best (Hungarian assignment on class, length and width,
:func:`~sumo_scendiff.core.matching.assign`): the scene's vehicles follow the scenario's mix and the
longest boxes get the longest types. A type is given only where its lane allows its class and where
its box, around the centre the model drew, keeps clear of the vehicles ahead and behind; an agent no
drawn type fits gets the nearest type that fits (by the mix among those as near). Without a demand
there is no mix and the seeder keeps the model's sizes.
"""
from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from typing import Mapping, Sequence

import numpy as np
import shapely

from ..core.geometry import OVERLAP_AREA, box_polygons
from ..core.matching import assign
from ..core.scene import VEHICLE_CLASSES, Scene
from ..tokens.file import TokenFileError

# SUMO's default vehicle type (DEFAULT_VEHTYPE, a passenger car): what a vehicle drives with where
# neither its vType nor its vClass says otherwise
DEFAULT_LENGTH, DEFAULT_WIDTH, DEFAULT_MIN_GAP = 5.0, 1.8, 2.5   # m
DEFAULT_ACCEL, DEFAULT_DECEL = 2.6, 4.5                          # m/s²

# vClasses the model never draws (it generates road motor vehicles on car lanes)
NOT_DRAWN = frozenset({"pedestrian", "bicycle", "tram", "rail_urban", "rail", "rail_electric", "rail_fast",
                       "ship", "ignoring", "wheelchair", "scooter", "cable_car", "subway", "aircraft",
                       "drone", "container"})
# the model's classes (core.scene.VEHICLE_CLASSES) and the SUMO vClasses of the same kind
KIND = {"passenger": "passenger", "private": "passenger", "taxi": "passenger", "evehicle": "passenger",
        "vip": "passenger", "authority": "passenger", "army": "passenger", "emergency": "delivery",
        "custom1": "passenger", "custom2": "passenger", "delivery": "delivery", "truck": "truck",
        "trailer": "truck", "bus": "bus", "coach": "bus", "motorcycle": "motorcycle", "moped": "motorcycle"}
# the assignment's cost: metres of length and width apart, and another kind of vehicle
LENGTH_SCALE, WIDTH_SCALE, OTHER_KIND = 1.0, 0.25, 2.0
NEAR = 0.5            # types within this cost of the nearest are "as near" (the mix chooses among them)
ROOM_MARGIN = 0.5     # m: a longer type keeps at least this gap to the vehicles ahead and behind
LISTED = 12          # vType ids an unknown name's error lists
DRAWN_KEY = "fleet"   # scene.meta: agent index -> (vType id, drawn length, drawn width)


# a generic parameter of a seeded vehicle's own vType naming the scenario vType it copies
PARENT_PARAM = "scendiff.parent"


@dataclass(frozen=True)
class VType:
    id: str
    vclass: str
    length: float
    width: float
    min_gap: float
    emission: str

    @property
    def kind(self) -> str:
        return KIND.get(self.vclass, "passenger")


def read_vtype(sim, tid: str) -> VType:
    """One vType as the running simulation has it."""
    t = sim.vehicletype
    return VType(tid, t.getVehicleClass(tid), float(t.getLength(tid)), float(t.getWidth(tid)),
                 float(t.getMinGap(tid)), t.getEmissionClass(tid))


@dataclass(frozen=True)
class DemandTypes:
    """What the fleet takes from the scenario's files: its vTypeDistributions (id -> member vType id ->
    probability) and the vehicles its route files depart per vType id as they name it (a
    distribution's under its own id; :func:`_expand` shares them out)."""
    dists: Mapping[str, Mapping[str, float]]
    departs: Mapping[str, float]


def demand_types(routes: Sequence[str], additional: Sequence[str] = ()) -> DemandTypes:
    """The :class:`DemandTypes` of route files ``routes`` and additional files ``additional``, read
    as SUMO reads them (core.sumo_xml: includes, gzip, any root) in one streaming pass, and kept per
    version (path, size, modification time) of each file named: a run asks for them for its
    requests and again for each scene's seeder, a sweep for each task, and a city's demand takes
    seconds to read (docs/corpus.md). A file changed behind an ``<include>`` alone is not seen. The
    answer is shared by every caller: read it, do not change it."""
    return _scan(tuple(map(_version, routes)), tuple(map(_version, additional)))


def _version(path: str) -> tuple:
    try:
        st = os.stat(path)
    except OSError:   # no such file: the reading names it (core.sumo_xml.XmlError)
        return os.path.abspath(path), None, None
    return os.path.abspath(path), st.st_size, st.st_mtime_ns


@lru_cache(maxsize=8)
def _scan(routes: tuple, additional: tuple) -> DemandTypes:
    from ..core.sumo_xml import elements
    dists: dict[str, dict[str, float]] = {}
    departs: Counter = Counter()
    for files, departing in ((routes, True), (additional, False)):
        for _, el in elements([f[0] for f in files], ("vTypeDistribution", "vehicle", "trip", "flow")):
            if el.tag == "vTypeDistribution":
                members = _members(el)
                if members:
                    dists[el.get("id")] = members
            elif departing:
                departs[el.get("type") or "DEFAULT_VEHTYPE"] += flow_count(el) if el.tag == "flow" else 1.0
    return DemandTypes(dists, departs)


def _members(el) -> dict[str, float]:
    """A ``<vTypeDistribution>``'s members and their probabilities (SUMO's: a member's own
    ``probability``, or the distribution's ``probabilities`` list, else 1; normalised); empty where
    they add up to nothing."""
    names = (el.get("vTypes") or "").split()
    probs = [float(p) for p in (el.get("probabilities") or "").split()]
    members = {n: probs[k] if k < len(probs) else 1.0 for k, n in enumerate(names)}
    for c in el.findall("vType"):
        members[c.get("id")] = float(c.get("probability") or 1.0)
    total = sum(members.values())
    return {n: p / total for n, p in members.items()} if total > 0 else {}


def vtype_distributions(paths: Sequence[str]) -> dict[str, dict[str, float]]:
    """Every vTypeDistribution in ``paths``: id -> member vType id -> probability (:func:`demand_types`)."""
    return {k: dict(v) for k, v in demand_types((), paths).dists.items()}


def file_mix(paths: Sequence[str], dists: Mapping[str, Mapping[str, float]]) -> Counter:
    """The vehicles the route files ``paths`` depart, per vType (a flow's: :func:`flow_count`; a
    distribution's vehicles shared by its probabilities ``dists``)."""
    return _expand(demand_types(paths).departs, dists)


def flow_count(el) -> float:
    """About how many vehicles a ``<flow>`` departs: its ``number``, else its span over its
    ``period`` or at its ``vehsPerHour`` or ``probability`` per second; one where it gives no span.
    ``el``: an ElementTree element (core.sumo_xml)."""
    from ..core.sumo_xml import seconds
    if el.get("number"):
        return float(el.get("number"))
    end, begin = seconds(el.get("end")), seconds(el.get("begin") or "0")
    if end is None or begin is None:       # no end (or one SUMO reads otherwise)
        return 1.0
    span = end - begin
    period = el.get("period") or ""
    if period.startswith("exp("):          # SUMO's random departures at this rate per second
        rate = float(period[4:].rstrip(")"))
    elif period:
        rate = 1.0 / (seconds(period) or float("inf"))
    elif el.get("vehsPerHour"):
        rate = float(el.get("vehsPerHour")) / 3600.0
    else:
        rate = float(el.get("probability") or 0.0)
    return max(span * rate, 1.0)


def _sim_files(sim) -> tuple[list[str], list[str]]:
    """The route and additional files the running simulation loaded (those that can be read here)."""
    def files(option: str) -> list[str]:
        try:
            value = sim.simulation.getOption(option)
        except Exception:   # SUMO < 1.19 has no getOption
            return []
        return [p for p in value.replace(",", " ").split() if os.path.isfile(p)]
    return files("route-files"), files("additional-files")


class Fleet:
    """The vTypes a running simulation knows (:meth:`read`) and the demand's mix of them."""

    def __init__(self, sim, share: Mapping[str, float], dists: Mapping[str, Mapping[str, float]] = None):
        self.sim = sim
        self.names = frozenset(sim.vehicletype.getIDList())
        self.dists = {k: dict(v) for k, v in (dists or {}).items() if k in self.names}
        self._types: dict[str, VType] = {}
        kept = {k: float(v) for k, v in share.items()
                if v > 0 and k in self.names and k not in self.dists and self.get(k).vclass not in NOT_DRAWN}
        total = sum(kept.values())
        self.share = {k: v / total for k, v in sorted(kept.items())} if total > 0 else {}

    @classmethod
    def read(cls, sim, exclude: str = "", mix: Mapping[str, float] | None = None,
             files: Sequence[str] | None = None) -> "Fleet":
        """The fleet of ``sim``: its vTypes; the distributions of ``files`` (route and additional
        files; default: those the simulation loaded); the mix ``mix`` if given, else the vehicles
        present whose id does not start with ``exclude`` (the seeder's own), else the route files'."""
        found = demand_types(*(_sim_files(sim) if files is None else (files, ())))
        if mix is None:
            mix = Counter(scenario_type(sim.vehicle.getTypeID(v), v) for v in sim.vehicle.getIDList()
                          if not (exclude and v.startswith(exclude)))
        if not mix:
            mix = _expand(found.departs, found.dists)
        return cls(sim, _expand(mix, found.dists), found.dists)

    # ---- the types ----------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """Whether the scenario has a demand whose fleet the seeded vehicles take."""
        return bool(self.share)

    def __contains__(self, name) -> bool:
        return name in self.names

    def get(self, name: str) -> VType:
        if name not in self._types:
            self._types[name] = read_vtype(self.sim, name)
        return self._types[name]

    def member(self, name: str, length: float, width: float, kind: str, rng) -> str:
        """``name`` itself, or for a distribution the member that fits a drawn box (by its
        probabilities among those as near)."""
        if name not in self.dists:
            return name
        probs = self.dists[name]
        members = [m for m in probs if m in self.names and m not in self.dists]
        if not members:
            return name
        cost = np.array([self._cost(self.get(m), length, width, kind) for m in members])
        return self._pick(members, cost, [probs[m] for m in members], rng)

    def nearest(self, length: float, width: float, kind: str, allowed, room: float, rng,
                same_kind: bool = False) -> str | None:
        """The mix's type nearest a drawn box among those ``allowed`` (vClass -> bool) that fit in
        ``room`` (m of length), sampled by the mix among those as near; None if none fits. With
        ``same_kind`` only those of ``kind`` where the mix has one (a token's vclass)."""
        names = [n for n in self.share if allowed(self.get(n).vclass) and self.get(n).length <= room]
        if same_kind:
            names = [n for n in names if self.get(n).kind == kind] or names
        if not names:
            return None
        cost = np.array([self._cost(self.get(n), length, width, kind) for n in names])
        return self._pick(names, cost, [self.share[n] for n in names], rng)

    def token_vtypes(self, tokens: Sequence, source: str) -> list:
        """``tokens`` (one window's dicts, a token file's agents in order) with each ``vtype`` checked
        against the scenario and its size given where the token gives none; an unknown name raises
        :class:`~sumo_scendiff.tokens.file.TokenFileError` naming ``source`` and the name."""
        out = []
        for i, tok in enumerate(tokens):
            name = tok.get("vtype") if isinstance(tok, Mapping) else None
            if name is None:
                out.append(tok)
                continue
            if name not in self.names:
                known = sorted(n for n in self.names if not n.startswith("DEFAULT_"))
                listed = ", ".join(known[:LISTED]) + (f" and {len(known) - LISTED} more" if len(known) > LISTED else "")
                raise TokenFileError(f"{source}: agents[{i}]: vtype: the scenario has no vType {name!r}"
                                     f" (it has {listed or 'none but SUMO defaults'})")
            tok = dict(tok)
            if tok.get("length") is None and tok.get("width") is None:
                probs = self.dists.get(name, {name: 1.0})
                t = self.get(max(probs, key=probs.get))
                tok["length"], tok["width"] = t.length, t.width
            out.append(tok)
        return out

    # ---- a scene's vehicles --------------------------------------------------------------------
    def assign(self, scene: Scene, others: np.ndarray, lead: np.ndarray, gap: np.ndarray, net,
               named: Sequence | None, rng, sized: Sequence | None = None) -> tuple[list[str | None], dict[int, str]]:
        """(per agent of ``scene`` the vType it is seeded as, None: the model's box on SUMO's default
        type as without a demand; the agents not to seed, with why). Each box is resized to its
        type's around the same centre (``scene.meta[DRAWN_KEY]`` keeps what was drawn). ``named``:
        per agent a type asked for (a token's ``vtype``, a demand vehicle's own) or None; ``others``
        the host's boxes (scene frame); ``lead``, ``gap``: :meth:`Seeder.leaders` of the agents' and
        then the host's boxes (the room a longer type has). ``sized``: per agent :func:`own_size` of
        its user token: such an agent keeps its box and takes the mix's type nearest it (what the
        token gives is what SUMO gets; the seeder gives the vehicle that size), not a drawn one."""
        n = len(scene)
        out: list[str | None] = [None] * n
        if not n:
            return out, {}
        boxes = scene.boxes
        before = boxes[:, :5].copy()
        kinds = [VEHICLE_CLASSES[int(c)] for c in scene.vclass]
        for i in range(n):
            name = named[i] if named is not None else None
            if name is not None and name in self.names:
                out[i] = self.member(name, boxes[i, 3], boxes[i, 4], kinds[i], rng)
        own = [out[i] is None and sized is not None and bool(sized[i]) for i in range(n)]
        if self.active:
            allowed = _lane_rules(scene, net)
            for i in np.flatnonzero(own):
                out[i] = self.nearest(boxes[i, 3], boxes[i, 4], kinds[i], allowed[i], np.inf, rng,
                                      same_kind=sized[i] == "class")
            room = room_for(boxes[:, 3], lead, gap, n)
            self._draw(out, kinds, allowed, room, boxes, rng, own)
        drawn = {}
        for i, name in enumerate(out):
            if name is not None:
                t = self.get(name)
                drawn[i] = (name, float(boxes[i, 3]), float(boxes[i, 4]))
                if not own[i]:
                    boxes[i, 3], boxes[i, 4] = t.length, t.width
                    scene.vclass[i] = VEHICLE_CLASSES.index(t.kind)
        scene.meta[DRAWN_KEY] = {**scene.meta.get(DRAWN_KEY, {}), **drawn}
        return out, crowded(before, boxes[:, :5], others, out)

    def _draw(self, out: list, kinds: list[str], allowed: list, room: np.ndarray, boxes: np.ndarray, rng,
              own: list) -> None:
        """The agents without a type yet (but those keeping their own size): a fleet drawn from the
        mix, each drawn type given to the agent it fits best (allowed on its lane, within its room);
        the rest the nearest that fits."""
        free = [i for i, name in enumerate(out) if name is None and not own[i]]
        if not free:
            return
        names = list(self.share)
        drawn = [names[k] for k in rng.choice(len(names), size=len(free), p=list(self.share.values()))]
        types = [self.get(d) for d in drawn]
        cost = np.array([[self._cost(t, boxes[i, 3], boxes[i, 4], kinds[i]) for t in types] for i in free])
        ok = np.array([[allowed[i](t.vclass) and t.length <= room[i] for t in types] for i in free])
        rows, cols = assign(cost, ok)
        for r, c in zip(rows, cols):
            out[free[r]] = drawn[c]
        for i in free:
            if out[i] is None:   # no drawn type fits: the nearest that does, else the nearest allowed
                out[i] = (self.nearest(boxes[i, 3], boxes[i, 4], kinds[i], allowed[i], room[i], rng)
                          or self.nearest(boxes[i, 3], boxes[i, 4], kinds[i], allowed[i], np.inf, rng))

    @staticmethod
    def _cost(t: VType, length: float, width: float, kind: str) -> float:
        return (abs(t.length - length) / LENGTH_SCALE + abs(t.width - width) / WIDTH_SCALE
                + (OTHER_KIND if t.kind != kind else 0.0))

    @staticmethod
    def _pick(names: list[str], cost: np.ndarray, weight: Sequence[float], rng) -> str:
        near = np.flatnonzero(cost <= cost.min() + NEAR)
        w = np.asarray(weight, np.float64)[near]
        w = w / w.sum() if w.sum() > 0 else np.full(len(near), 1.0 / len(near))
        return names[int(near[rng.choice(len(near), p=w)])]


def own_size(token) -> str | None:
    """What a user's token fixes of its vehicle's size: "class" (it gives ``vclass``), "size" (it gives
    ``length`` or ``width``), or None (neither, or it names a ``vtype``, which has its own size)."""
    if not isinstance(token, Mapping) or token.get("vtype") is not None:
        return None
    if token.get("vclass") is not None:
        return "class"
    return "size" if token.get("length") is not None or token.get("width") is not None else None


def scenario_type(type_id: str, vehicle: str) -> str:
    """The scenario's vType a vehicle is of: its own copy's (``{type}@{vehicle}``, SUMO's singular type of
    a vehicle whose type parameters were set on the vehicle, by the user's TraCI or the seeder) parent."""
    suffix = f"@{vehicle}"
    return type_id[: -len(suffix)] if type_id.endswith(suffix) else type_id


def _expand(mix: Mapping[str, float], dists: Mapping[str, Mapping[str, float]]) -> Counter:
    """A mix with each distribution's share given to its members by their probabilities."""
    out: Counter = Counter()
    for name, n in mix.items():
        for member, p in dists.get(name, {name: 1.0}).items():
            out[member] += n * p
    return out


def crowded(before: np.ndarray, after: np.ndarray, others: np.ndarray, names: list) -> dict[int, str]:
    """The agents whose box as their vType's (``after``) overlaps another vehicle's that their drawn
    box (``before``) did not (no type fitted between the vehicles ahead and behind): of two agents
    the one that grew more is not seeded, the host's vehicles (``others``) stay."""
    n = len(after)
    new = box_polygons(np.concatenate([after, others[:, :5]]))
    old = box_polygons(np.concatenate([before, others[:, :5]]))
    rows, cols = shapely.STRtree(new).query(new[:n], predicate="intersects")
    grew = after[:, 3] - before[:, 3]
    out: dict[int, str] = {}
    for i, j in sorted(zip(rows.tolist(), cols.tolist())):
        if i == j or i in out or j in out or (j < n and j < i):
            continue
        if shapely.area(shapely.intersection(new[i], new[j])) <= OVERLAP_AREA or \
                shapely.area(shapely.intersection(old[i], old[j])) > OVERLAP_AREA:
            continue
        k = j if j < n and (grew[j], j) > (grew[i], i) else i
        out[k] = f"as vType {names[k]!r} its box overlaps another vehicle's (no room between them)"
    return out


def room_for(length: np.ndarray, lead: np.ndarray, gap: np.ndarray, n: int) -> np.ndarray:
    """Per agent (the first ``n`` of the boxes ``lead``/``gap`` describe) the longest box that
    keeps :data:`ROOM_MARGIN` to the vehicles ahead and behind with its centre where it was drawn."""
    behind = np.full(len(lead), np.inf)
    for j, i in enumerate(lead):
        if i >= 0:
            behind[i] = min(behind[i], gap[j])
    clear = np.minimum(gap[:n], behind[:n]) - ROOM_MARGIN
    return np.asarray(length, np.float64) + 2.0 * np.maximum(clear, 0.0)


def _lane_rules(scene: Scene, net) -> list:
    """Per agent a function vClass -> whether the lane its centre stands on allows it (any class
    where no lane is found: the seeder refuses such an agent anyway)."""
    w = scene.window
    xy = w.scene_to_world(scene.boxes[:, :2])
    yaw = np.asarray(w.yaw_to_world(scene.boxes[:, 2]))
    out = []
    for (x, y), h in zip(xy, yaw):
        hit = net.lookup(float(x), float(y), float(h))
        lane = net.sumo_net.getLane(hit[0].id) if hit is not None and net.sumo_net is not None else None
        out.append((lambda c, lane=lane: lane.allows(c)) if lane is not None else (lambda c: True))
    return out


__all__ = ["DRAWN_KEY", "DemandTypes", "Fleet", "VType", "crowded", "demand_types", "file_mix", "flow_count", "read_vtype", "room_for", "vtype_distributions"]
