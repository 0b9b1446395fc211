"""Co-simulation API: seed generated traffic into a simulation someone else is running.

    import libsumo as sim                                # or traci (e.g. a CARLA-SUMO bridge)
    sim.start(["sumo", "-n", "city.net.xml", "-r", "demand.rou.xml", "--lateral-resolution", "0.8"])
    cosim = CoSimulation(sim, Network.load("city.net.xml"), ScenarioGenerator.load())
    ...                                                  # the caller steps as it likes
    seeding = cosim.seed_around("ego", p_mask=0.7)       # fill the 100 m around the ego
    sim.simulationStep()
    cosim.verify(seeding)                                # who stands where it was generated, settled
    while running:
        sim.simulationStep()
        cosim.reseed_ahead("ego", every_m=60.0)          # new traffic ahead every 60 m the ego drives

Units: distances in metres (``ahead_m``, ``every_m``; token ``x``/``y``/``length``/``width``), times in
seconds, speeds in m/s, headings in radians counter-clockwise from +x (east). Token positions are in
the window's frame (x along the ego's heading, metres from the window centre) unless a token file says
``frame = "world"``.
Vehicles already in the window are kept: they become agent tokens (pose, size, speed), so the
model fills in *around* them (the paper's scene infill); generated agents that the model put on
top of them (matched to their tokens, or overlapping their boxes) are not seeded. The caller's
simulation is never stopped by a refused vehicle: it is reported in ``seeding.report.refused``.
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field

import numpy as np
import shapely

from ..core.geometry import (
    T0,
    TIMES,
    Window,
    box_polygons,
    pose_to_sumo,
    sumo_to_pose,
    wrap_angle,
)
from ..core.matching import match_agents
from ..core.scene import Scene
from ..map.network import Network
from .fleet import own_size
from .request import counted_as_asked, generation_inputs, window_request
from .seed_report import before_status
from .seeding import Seeder, SeedReport
from .settle import krauss_safe_speed
from .sumo import died

EXISTING_MARGIN = 10.0   # m beyond the window where existing vehicles still block generated ones
OVERLAP_BUFFER = 0.3     # m of clearance kept around existing vehicles
GUARD_MARGIN = 60.0      # m beyond the window whose host vehicles must be able to stop behind the agents
SAFE_SPEED_SLACK = 0.1   # m/s a host vehicle may be above its safe speed behind a seeded one (rounding)
LOOSE_HEADING = 0.5      # rad: a token's own vehicle may turn this far from its heading (Seeding.lost_tokens)


@dataclass
class Existing:
    """Vehicles of the host simulation around a window (scene frame)."""
    ids: list[str]
    boxes: np.ndarray            # (N, 5) x, y, yaw, length, width
    speed: np.ndarray            # (N,)
    inside: np.ndarray           # (N,) bool: centre inside the window (those become tokens)

    def tokens(self) -> list[dict]:
        return [{"x": float(b[0]), "y": float(b[1]), "heading": float(b[2]), "length": float(b[3]),
                 "width": float(b[4]), "speed": float(v)}
                for b, v, k in zip(self.boxes, self.speed, self.inside) if k]

    def token_ids(self) -> list[str]:
        return [i for i, k in zip(self.ids, self.inside) if k]


@dataclass
class Seeding:
    """One seeded window: the generated scene, which token produced each agent, the SUMO ids."""
    scene: Scene                          # the agents that were seeded (scene frame)
    report: SeedReport                    # agent index -> vehicle id / refusal / misplacement
    tokens: list[dict]                    # every token given to the model (user's, then existing)
    token_source: list[str]               # "user" or the existing vehicle's id, per token
    token_of: list[int | None]            # per seeded agent: index into tokens, or None
    seed: int = 0
    p_mask: float = 1.0
    meta: dict = field(default_factory=dict)
    # the generated agents not handed to the seeder for a vehicle already there: the model's copy of
    # it (status existing: :attr:`copies`), or a box on or too close ahead of one (status dropped:
    # :attr:`dropped`); their reasons and tokens, as for the seeded agents
    before: Scene | None = None
    before_reason: list[str] = field(default_factory=list)
    before_token: list[int | None] = field(default_factory=list)

    @property
    def agent_ids(self) -> list[str]:
        return list(self.report.ids.values())

    @property
    def copies(self) -> int:
        """The model's copies of a vehicle already there: that vehicle kept, the copy not added (``existing``)."""
        return sum(before_status(t, self.token_source) == "existing" for t in self.before_token)

    @property
    def dropped(self) -> int:
        """The agents dropped for a vehicle already there, not its copy: a box on or too close ahead of one
        (``dropped``, among those the seeder's own rules drop; scene.json ``dropped_on_existing``)."""
        return len(self.before_token) - self.copies

    def counts(self) -> dict[str, int]:
        """Every generated agent once: generated = placed + misplaced + refused + existing + dropped."""
        out = self.report.counts(len(self.scene))
        out["generated"] += len(self.before_token)
        out["existing"] += self.copies     # the host's own vehicles redrawn: kept, the copies not added
        out["dropped"] += self.dropped
        return out

    def lost_tokens(self) -> dict[int, str]:
        """The user's positioned tokens (index -> why) no vehicle in the simulation realises: the
        model drew none there (the generator's own warning for it where it gave one), or our rules
        dropped it, or SUMO refused it. A misplaced one is a vehicle, and not lost."""
        said: dict[int, str] = {}
        for line in self.scene.meta.get("token_warnings", ()):
            k = line.split(" ", 2)[1] if line.startswith("token ") else ""
            if k.isdigit():
                said.setdefault(int(k), line)
        user = [k for k, (t, src) in enumerate(zip(self.tokens, self.token_source))
                if src == "user" and t.get("x") is not None]
        agent = self._stands_for(user)
        early = {t: why for t, why in zip(self.before_token, self.before_reason) if t is not None}
        out = {}
        for k in user:
            if k in agent:
                status, why = self.report.status(agent[k])
                if status in ("refused", "dropped"):
                    out[k] = f"its vehicle was {status}: {why}"
            elif k in early:
                out[k] = f"its vehicle was dropped: {early[k]}"
            else:
                out[k] = said.get(k, "the model drew no vehicle there")
        return out

    def _stands_for(self, user: list[int]) -> dict[int, int]:
        """Token index -> the seeded agent standing for it: the one matched to it (``token_of``), else
        among the agents matched to none the one within the matching distance and LOOSE_HEADING of it
        (a vehicle snapped onto a curved lane turns further from a token's heading than the paper's
        matching allows, but it is that token's vehicle)."""
        agent = {t: i for i, t in enumerate(self.token_of) if t is not None}
        left = [k for k in user if k not in agent]
        free = [i for i, t in enumerate(self.token_of) if t is None]
        if left and free:
            tb = np.array([[self.tokens[k]["x"], self.tokens[k]["y"], np.nan if self.tokens[k].get("heading") is None
                            else self.tokens[k]["heading"]] for k in left], np.float64)
            gi, ti = match_agents(self.scene.boxes[free, :3], tb, max_heading=LOOSE_HEADING)
            agent.update({left[int(t)]: free[int(g)] for g, t in zip(gi, ti)})
        return agent


def token_assignment(scene: Scene, tokens: list[dict]) -> list[int | None]:
    """Per generated agent, the token it realises (Hungarian matching on position and heading,
    :func:`~sumo_scendiff.evaluate.metrics.match_agents`); tokens without a position match nothing."""
    out: list[int | None] = [None] * len(scene)
    pos = [k for k, t in enumerate(tokens) if t.get("x") is not None and t.get("y") is not None]
    if not pos or not len(scene):
        return out
    tb = np.array([[tokens[k]["x"], tokens[k]["y"],
                    np.nan if tokens[k].get("heading") is None else tokens[k]["heading"]] for k in pos])
    gi, ti = match_agents(scene.boxes[:, :3], tb)
    for g, t in zip(gi, ti):
        out[int(g)] = pos[int(t)]
    return out


def on_existing(scene: Scene, token_of: list[int | None], token_source: list[str],
                existing: Existing) -> dict[int, str]:
    """The generated agents (index -> why) not to seed beside the host's vehicles: the model's copy of
    a vehicle already there (matched to its token), or a box within ``OVERLAP_BUFFER`` m of one."""
    why = {i: f"vehicle {token_source[t]!r} was already there and is kept; the model's copy of it is not added"
           for i, t in enumerate(token_of) if before_status(t, token_source) == "existing"}
    if len(existing.ids) and len(scene):
        hosts = shapely.buffer(box_polygons(existing.boxes), OVERLAP_BUFFER)
        agent, host = shapely.STRtree(hosts).query(box_polygons(scene.boxes), predicate="intersects")
        for i, j in sorted(zip(agent.tolist(), host.tolist())):
            why.setdefault(i, f"its box overlaps vehicle {existing.ids[j]!r}, already there")
    return why


def _sumo_gone(method):
    """The method, raising :class:`~sumo_scendiff.sim.sumo.SumoDied` (SUMO's last words, one line)
    where the caller's traci SUMO ends in the middle of it, whatever traci call meets the end."""
    @functools.wraps(method)
    def guarded(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except Exception as e:
            gone = died(e, self.sim)
            if gone is None:
                raise
            raise gone from None
    return guarded


def _with(existing: Existing, more: Existing) -> Existing:
    """``existing`` and the vehicles of ``more`` it does not name."""
    add = [k for k, vid in enumerate(more.ids) if vid not in set(existing.ids)]
    return Existing(existing.ids + [more.ids[k] for k in add],
                    np.concatenate([existing.boxes.reshape(-1, 5), more.boxes[add].reshape(-1, 5)]),
                    np.concatenate([np.asarray(existing.speed, np.float64).reshape(-1), more.speed[add]]),
                    np.concatenate([existing.inside, more.inside[add]]))


def too_close_ahead(sim, scene: Scene, existing: Existing, why: dict[int, str]) -> dict[int, str]:
    """The generated agents (index -> why) that would stand nearer ahead of a host vehicle than it can
    stop behind at its speed (Krauss' safe speed with its own decel, tau and minGap): seeded, they
    would make the host's vehicle -- the caller's ego among them -- brake beyond its decel. Agents
    already in ``why`` are left out; once one is dropped, the next ahead is the host's leader."""
    out: dict[int, str] = {}
    while True:
        more = _too_close(sim, scene, existing, {**why, **out})
        if not more:
            return out
        out.update(more)


def _too_close(sim, scene: Scene, existing: Existing, why: dict[int, str]) -> dict[int, str]:
    """One pass of :func:`too_close_ahead`: each host vehicle's nearest leader among the agents."""
    if not len(existing.ids) or not len(scene):
        return {}
    keep = np.array([i not in why for i in range(len(scene))], bool)
    idx = np.flatnonzero(keep)
    lead, gap = Seeder.leaders(existing.boxes, scene.boxes[idx])
    out: dict[int, str] = {}
    n = len(existing.ids)
    for e, (j, g) in enumerate(zip(lead.tolist(), gap.tolist())):
        if j < n:            # its nearest leader is the host's own (or none)
            continue
        a, vid = int(idx[j - n]), existing.ids[e]
        try:
            b, tau, min_gap = sim.vehicle.getDecel(vid), sim.vehicle.getTau(vid), sim.vehicle.getMinGap(vid)
        except Exception:    # left the simulation meanwhile
            continue
        safe = krauss_safe_speed(g - min_gap, max(float(scene.speed[a, T0]), 0.0), b, tau)
        if float(existing.speed[e]) > safe + SAFE_SPEED_SLACK:
            out.setdefault(a, f"{g:.1f} m ahead of vehicle {vid!r}, which cannot stop behind it from "
                              f"{float(existing.speed[e]):.1f} m/s")
    return out


class CoSimulation:
    """Seeds generated traffic into the caller's simulation. Every method raises
    :class:`~sumo_scendiff.sim.sumo.SumoDied` if the caller's SUMO (traci) ends in the middle."""

    def __init__(self, sim, net: Network, generator, seed: int = 0, prefix: str = "sd"):
        self.sim, self.net, self.generator = sim, net, generator
        self.seeder = Seeder(sim, net, prefix=prefix, seed=seed)
        self.seed = seed
        self.count = 0
        self._last_seed_xy: dict[str, np.ndarray] = {}

    # ---- the host's vehicles ------------------------------------------------------------------
    @_sumo_gone
    def existing(self, window: Window, margin: float = EXISTING_MARGIN) -> Existing:
        """The host's vehicles within ``margin`` m of the window (those inside it become tokens)."""
        sim, ids, boxes, speed = self.sim, [], [], []
        reach = window.size * np.sqrt(0.5) + margin
        for vid in sim.vehicle.getIDList():
            x, y = sim.vehicle.getPosition(vid)
            if np.hypot(x - window.cx, y - window.cy) > reach:
                continue
            length = float(sim.vehicle.getLength(vid))
            cx, cy, yaw = sumo_to_pose(x, y, sim.vehicle.getAngle(vid), length)
            ids.append(vid)
            boxes.append([cx, cy, yaw, length, float(sim.vehicle.getWidth(vid))])
            speed.append(float(sim.vehicle.getSpeed(vid)))
        b = np.asarray(boxes, np.float64).reshape(-1, 5)
        local = b.copy()
        if len(b):
            local[:, :2] = window.world_to_scene(b[:, :2])
            local[:, 2] = window.yaw_to_scene(b[:, 2])
        inside = window.contains(local[:, :2]) if len(b) else np.zeros(0, bool)
        keep = window.contains(local[:, :2], margin=-margin) if len(b) else inside
        return Existing([i for i, k in zip(ids, keep) if k], local[keep],
                        np.asarray(speed, np.float64).reshape(-1)[keep], inside[keep])

    # ---- seeding ------------------------------------------------------------------------------
    @_sumo_gone
    def place(self, scene: Scene, tokens: list[dict], token_source: list[str], existing: Existing,
              seed: int = 0, p_mask: float = 1.0) -> Seeding:
        """Seed a generated ``scene`` whose tokens were ``tokens`` (user's, then existing vehicles')."""
        token_of = token_assignment(scene, tokens)
        why = on_existing(scene, token_of, token_source, existing)
        # the host's vehicles that could reach the window's agents, the caller's ego behind it too
        why.update(too_close_ahead(self.sim, scene, _with(existing, self.existing(scene.window, GUARD_MARGIN)), why))
        idx = np.array([i for i in range(len(scene)) if i not in why], np.int64)
        gone = np.array(sorted(why), np.int64)
        sub = scene.select(idx)
        self.seeder.prefix = f"{self.seeder.prefix.split('.')[0]}.{self.count}."
        self.seeder.count = 0
        self.count += 1
        named = [None if token_of[i] is None else tokens[token_of[i]].get("vtype") for i in idx]   # sim/fleet.py
        sized = [None if token_of[i] is None or token_source[token_of[i]] != "user" else own_size(tokens[token_of[i]])
                 for i in idx]
        report = self.seeder.seed(sub, others=(existing.boxes, existing.speed), types=named, sized=sized)
        return Seeding(sub, report, tokens, token_source, [token_of[i] for i in idx],
                       seed=seed, p_mask=p_mask, before=scene.select(gone),
                       before_reason=[why[i] for i in gone.tolist()],
                       before_token=[token_of[i] for i in gone.tolist()])

    @_sumo_gone
    def seed_window(self, window: Window, tokens: list[dict] = (), p_mask: float | None = None,
                    seed: int | None = None, density: float | str | None = None,
                    vehicles: int | None = None) -> Seeding:
        """Generate around the vehicles already in ``window`` and seed the new agents.

        ``tokens``: the caller's agent tokens (window frame, see :mod:`~sumo_scendiff.tokens.encoding`);
        ``p_mask``: the global scene token (default 1.0 for a window without agent tokens, the
        caller's or the vehicles already there, else 0.5: ``tokens.file.default_p_mask``);
        ``density``: vehicles per km of car lane the window should hold, those already there
        included, "auto" (this simulation's own level around the window, sim.density) or "model"
        (the model's own level); ``vehicles``: that many in the window instead. Neither: "auto"
        while the simulation has traffic of its own, else the model's (``default_density``).
        """
        req = window_request(self.net, self.sim, window, self.existing(window), tokens,
                             fleet=self.seeder._known_types(), p_mask=p_mask, density=density,
                             vehicles=vehicles, has_density=self.generator.has_density,
                             signals=self.generator.config.signals)
        for line in req.warnings:
            warnings.warn(line, stacklevel=2)
        s = self.seed + self.count if seed is None else seed
        scene = self.generator.generate(self.net, [window], seed=s, config=counted_as_asked(self.generator.config, vehicles),
                                        **generation_inputs([req]))[0]
        return self.place(scene, req.tokens, req.sources, req.existing, seed=s, p_mask=req.p_mask)

    @_sumo_gone
    def ego_window(self, ego: str, ahead_m: float = 0.0, size: float = 100.0) -> Window:
        """The window centred ``ahead_m`` metres in front of vehicle ``ego``, turned with it."""
        x, y = self.sim.vehicle.getPosition(ego)
        cx, cy, yaw = sumo_to_pose(x, y, self.sim.vehicle.getAngle(ego), self.sim.vehicle.getLength(ego))
        return Window(cx + ahead_m * np.cos(yaw), cy + ahead_m * np.sin(yaw), float(yaw), size)

    @_sumo_gone
    def seed_around(self, ego: str, tokens: list[dict] = (), ahead_m: float = 0.0, **kw) -> Seeding:
        """Seed the window ``ahead_m`` metres in front of vehicle ``ego`` (turned with it)."""
        seeding = self.seed_window(self.ego_window(ego, ahead_m), tokens, **kw)
        # an ego gone from the simulation keeps no entry (a caller may name a new ego each episode)
        present = set(self.sim.vehicle.getIDList())
        for gone in [e for e in self._last_seed_xy if e not in present]:
            del self._last_seed_xy[gone]
        self._last_seed_xy[ego] = np.asarray(self.sim.vehicle.getPosition(ego))
        return seeding

    @_sumo_gone
    def reseed_ahead(self, ego: str, every_m: float = 60.0, ahead_m: float = 60.0, **kw) -> Seeding | None:
        """Once the ego has driven ``every_m`` metres since its last seeding, seed the window
        ``ahead_m`` metres in front of it; otherwise None. Call it each step."""
        for gone in self.sim.simulation.getArrivedIDList():    # egos that arrived in the last step
            self._last_seed_xy.pop(gone, None)
        xy = np.asarray(self.sim.vehicle.getPosition(ego))
        last = self._last_seed_xy.get(ego)
        if last is not None and np.hypot(*(xy - last)) < every_m:
            return None
        return self.seed_around(ego, ahead_m=ahead_m, **kw)

    @_sumo_gone
    def follow(self, seeding: Seeding, tau: float) -> int:
        """Hold every seeded agent on its generated future: place it at its interpolated pose and
        speed for ``tau`` seconds after seeding (0 < tau <= 2); the caller then steps. Returns how
        many agents were moved (agents without an observed future are left to SUMO; none in SUMO's
        mesoscopic model, which has no pose to hold a vehicle at: moveToXY does nothing there)."""
        if self.seeder.meso:
            return 0
        sc, w, sim = seeding.scene, seeding.scene.window, self.sim
        k = min(int(np.floor(tau)), len(TIMES) - T0 - 2)          # segment [T0 + k, T0 + k + 1]
        a = tau - k
        present, moved = set(sim.vehicle.getIDList()), 0
        for i, vid in seeding.report.ids.items():
            j = T0 + k
            if vid not in present or not sc.traj_mask[i, j:j + 2].all():
                continue
            p = (1 - a) * sc.traj[i, j, :2] + a * sc.traj[i, j + 1, :2]
            yaw = sc.traj[i, j, 2] + a * wrap_angle(sc.traj[i, j + 1, 2] - sc.traj[i, j, 2])
            xy = w.scene_to_world(p)
            fx, fy, angle = pose_to_sumo(xy[0], xy[1], float(w.yaw_to_world(yaw)), sc.boxes[i, 3])
            speed = (1 - a) * sc.speed[i, j] + a * sc.speed[i, j + 1]
            try:
                sim.vehicle.moveToXY(vid, "", -1, float(fx), float(fy), float(angle),
                                     keepRoute=self.seeder.keep_route)
                sim.vehicle.setPreviousSpeed(vid, float(speed))
                moved += 1
            except Exception as e:  # a vehicle SUMO removed meanwhile: leave it (not SUMO itself gone)
                if type(e).__name__ == "FatalTraCIError":
                    raise
                continue
        return moved

    @_sumo_gone
    def replay_future(self, seeding: Seeding, seconds: float = 2.0) -> None:
        """Step the simulation for ``seconds`` (<= 2) with every agent on its generated future,
        then hand it to SUMO (for hosts that let the co-simulation step)."""
        dt = float(self.sim.simulation.getDeltaT())
        for k in range(1, int(round(min(seconds, 2.0) / dt)) + 1):
            self.follow(seeding, k * dt)
            self.sim.simulationStep()

    @_sumo_gone
    def verify(self, seeding: Seeding, warn: bool = True) -> Seeding:
        """After the host's next step: agents not within 0.5 m / 0.1 rad of their generated pose, or
        not in SUMO at all (refused); then none faster than it can stop behind its leader
        (:meth:`Seeder.settle`). ``warn``: a warning for each of the caller's tokens that gives no
        vehicle (:meth:`Seeding.lost_tokens`; False: the caller reports them itself)."""
        self.seeder.verify(seeding.report)
        self.seeder.settle(seeding.report)
        for k, why in seeding.lost_tokens().items() if warn else ():
            warnings.warn(f"token {k}: no vehicle: {why}", stacklevel=2)
        return seeding


__all__ = ["CoSimulation", "Seeding", "Existing", "token_assignment"]
