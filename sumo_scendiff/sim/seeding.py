"""Seeder: generated agents -> real SUMO vehicles at their generated poses (libsumo or traci).

    import libsumo as sim                      # or traci, connected to sumo / sumo-gui
    seeder = Seeder(sim, net)
    report = seeder.seed(scene)                # vehicle.add + vehicle.moveToXY(keepRoute=1) per agent
    sim.simulationStep()
    report = seeder.verify(report)             # who stands where it was generated (0.5 m, 0.1 rad)
    report = seeder.settle(report)             # minGaps that fit, none faster than it can stop

For each agent:
the lane it stands on (heading agreement; an internal junction lane gives the route its incoming
and outgoing edges, never starts a route), a route through the lanes of its +1/+2 s poses
(:mod:`~sumo_scendiff.sim.pose_routes`) and on by SUMO's router to a destination the host's traffic
drives to, or the network's fringe (:mod:`~sumo_scendiff.sim.routes`), a vehicle type with its box and a minGap that
fits the gap to the vehicle ahead in the scene and at most the width the network's junctions were
built for (``width_cap``), a departure speed that is its generated speed capped at the Krauss safe
speed behind that vehicle, then ``vehicle.add`` and ``vehicle.moveToXY``; a nose over the stop line is
first moved back onto its lane (:meth:`Seeder.fit_lane_ends`). Its vType and route are the vehicle's
own in SUMO, deleted with it (:meth:`Seeder.fit_type`, :meth:`Seeder.add_on_route`): a long
co-simulation does not pile up one of each per vehicle it seeded. SUMO
refusing a vehicle never crashes the host simulation: the agent is reported as refused. Before any
is added, agents on internal lanes of one junction whose links conflict are resolved
(:mod:`~sumo_scendiff.sim.drops`, :mod:`~sumo_scendiff.sim.junctions`): of two already in the area their links share, one is
seeded (the other is in ``report.dropped``); of two still before it, the later departs standing
and waits (in ``report.slowed``). After the
seeding step, :meth:`Seeder.settle` (:mod:`~sumo_scendiff.sim.settle`) checks both again against the
leader SUMO itself sees.

Generated agents are rarely on a lane's centre line. With SUMO's sublane model
(``--lateral-resolution``: on only where the user's scenario sets it or the CLIs' flag asks for it,
:mod:`~sumo_scendiff.sim.sumo` adds none) ``moveToXY`` with ``keepRoute=1`` keeps their lateral
offset; without it SUMO snaps them to the centre line (most generated agents then end up off their
pose; docs/evaluation.md, "Seeding SUMO: placement and hand-off"), so the Seeder uses ``keepRoute=2``
(exact pose, mapped to the nearest lane of its route) in such host simulations (the default).
"""
from __future__ import annotations

import numpy as np
import shapely

from ..core.geometry import OVERLAP_AREA, T0, box_polygons, pose_to_sumo, wrap_angle
from ..core.scene import VEHICLE_CLASSES, Scene
from ..map.network import Network
from .drops import Drops
from .fleet import PARENT_PARAM, Fleet
from .gaps import Gaps
from .junctions import JunctionConflicts
from .pose_routes import PoseRoutes
from .routes import RouteChooser
from .seed_report import STATUSES, SeedReport
from .settle import Settling, krauss_safe_speed
from .stop_lines import StopLines
from .sumo import mesoscopic

POS_TOLERANCE, YAW_TOLERANCE = 0.5, 0.1   # m, rad: "present where it was generated"
CLAMPED = 0.01         # m: a position on an internal lane this near its start is SUMO's clamp, not a pose
LANE_END_MARGIN = 0.05  # m: a nose further than this past its lane's end is moved back behind it


def sublane(sim) -> bool:
    """Whether the host simulation runs SUMO's sublane model (``--lateral-resolution`` > 0)."""
    try:
        return float(sim.simulation.getOption("lateral-resolution")) > 0
    except Exception:  # SUMO < 1.19 has no getOption
        return False


class Seeder(Gaps, Settling, StopLines, PoseRoutes, Drops):
    def __init__(self, sim, net: Network, prefix: str = "sd", seed: int = 0):
        self.sim, self.net, self.prefix = sim, net, prefix
        self.rng = np.random.default_rng(seed)
        self.count = 0
        self._via = self._internal_links()
        self.moved_from: dict[int, str] = {}     # fit_red_junctions: agent -> internal lane it was generated on
        self.keep_route = 1 if sublane(sim) else 2
        # SUMO's mesoscopic model: a vehicle stands in a segment of its edge (the one holding its
        # departPos), on no lane and at no pose (moveToXY does nothing there); docs/sumo-options.md
        self.meso = mesoscopic(sim)
        self.routes = RouteChooser(sim, net, exclude_prefix=prefix.split(".")[0])
        self.junctions = JunctionConflicts(net)
        self.resolve_junctions = True
        self.junction_stops = True               # settle: the junction ahead as a leader (link_stops)
        # netconvert puts the waiting position of a turn inside a junction where a vehicle of the
        # network's junction width clears the crossing stream (Network.junction_vehicle_width, 1.8 m
        # by default): a wider vehicle waiting there, or passing one that waits, touches the other
        # and SUMO registers a junction collision, whatever its class. So in SUMO a seeded vehicle is
        # at most that wide (scene.json keeps the generated width); None: the generated widths.
        self.width_cap: float | None = net.junction_vehicle_width
        self.fleet = None      # the scenario's vTypes and their mix (sim/fleet.py), read at the first seeding
        self._bases: set[str] = set()        # the per-class vTypes made (vtype)
        self._edge_routes: set[str] = set()  # the one-edge routes added (add_on_route)
        self._staged: set[str] = set()       # vehicles whose staging route is still in SUMO (add_on_route)
        # this seeding's vehicles -> ((lane, front pos) seeded on, first route edges, front point)
        self._placing: dict[str, tuple] = {}
        self._own_size: set[int] = set()     # this seeding's agents whose user token gave their size

    # ---- vehicle types ------------------------------------------------------------------------
    def _known_types(self) -> Fleet:
        """The scenario's fleet (its vTypes, the demand's mix of them), read once: at the first
        seeding the vehicles present are the demand's (none of the seeder's own yet)."""
        if self.fleet is None:
            self.fleet = Fleet.read(self.sim, exclude=self.prefix.split(".")[0])
        return self.fleet

    def vtype(self, vclass: int, parent: str | None = None) -> str:
        """The vType an agent is added as: ``parent`` where it is one of the scenario's vTypes
        (:meth:`Fleet.assign`), else the seeder's copy of SUMO's default with the class of its size
        (``{root}_{class}``: one per class, made once). The agent's box and minGap are its own
        (:meth:`fit_type`); SUMO's router takes this type, never a vehicle's own (a findRoute with a
        vehicle-specific type deletes it with the router's temporary vehicle)."""
        if parent is not None and parent in self._known_types():
            return parent
        vclass_name = VEHICLE_CLASSES[int(vclass)]
        tid = f"{self.prefix.split('.')[0]}_{vclass_name}"
        if tid not in self._bases:
            t = self.sim.vehicletype
            if tid not in t.getIDList():      # an earlier seeder in this simulation made it
                t.copy("DEFAULT_VEHTYPE", tid)
                t.setVehicleClass(tid, vclass_name)
            self._bases.add(tid)
        return tid

    def fit_type(self, vid: str, length: float, width: float, min_gap: float, parent: str | None,
                 own_size: bool = False) -> None:
        """The added vehicle's own size and minGap. SUMO gives a vehicle whose size or minGap is set
        (``vehicle.setMinGap`` ...) a type of its own, ``{type}@{vid}``, which settling can change
        without touching another vehicle and which SUMO deletes with the vehicle (the seeder leaves
        no vType behind). A copy of one of the scenario's vTypes (``parent``) differs only by a
        minGap fitted to the gap ahead where that is below its own, and the box a user's token gave it
        (``own_size``); else its box too."""
        v, t = self.sim.vehicle, self.sim.vehicletype
        if parent is not None:
            v.setMinGap(vid, min(float(min_gap), float(t.getMinGap(parent))))
            if own_size:
                v.setLength(vid, float(length))
                v.setWidth(vid, float(width))
            # an export writes the parent's own definition (its car-following model and parameters,
            # which TraCI cannot read back)
            t.setParameter(v.getTypeID(vid), PARENT_PARAM, parent)
            return
        v.setLength(vid, float(length))
        v.setWidth(vid, float(width))
        v.setMinGap(vid, float(min_gap))

    def add_on_route(self, vid: str, edges: list[str], **depart) -> None:
        """``vehicle.add`` on ``edges``, leaving no route behind: SUMO keeps a route added by id
        (``route.add``) for ever, but frees the route a vehicle is given (``vehicle.setRoute``) with
        the vehicle. So the vehicle is added on a staging route of its first edge (which SUMO checks
        its departure against), given its route, and the staging route removed; a route of one edge
        is the staging route, one per edge, shared."""
        sim = self.sim
        if len(edges) == 1:
            stage = f"{self.prefix.split('.')[0]}:{edges[0]}"
            if stage not in self._edge_routes:
                if stage not in sim.route.getIDList():     # an earlier seeder in this simulation added it
                    sim.route.add(stage, edges)
                self._edge_routes.add(stage)
            sim.vehicle.add(vid, stage, **depart)
            return
        sim.route.add(f"{vid}_route", edges[:1])
        self._staged.add(vid)
        sim.vehicle.add(vid, f"{vid}_route", **depart)
        sim.vehicle.setRoute(vid, edges)
        self._drop_stage(vid)

    def _drop_stage(self, vid: str) -> None:
        """Remove ``vid``'s staging route (:meth:`add_on_route`), if it still has one."""
        if vid not in self._staged:
            return
        self._staged.discard(vid)
        try:
            self.sim.route.remove(f"{vid}_route")
        except Exception:   # a SUMO without route.remove keeps it
            pass

    # ---- seeding --------------------------------------------------------------------------------
    def fit_lane_ends(self, scene: Scene, report: SeedReport, others: np.ndarray) -> None:
        """Agents standing on a normal lane with the nose past its end (over the stop line) are moved
        back along their heading until the nose is at the end, the whole trajectory with them; the
        scene records the pose. SUMO keeps a vehicle on its lane within the lane's length: placed
        there by ``moveToXY`` it stands where asked for one step, but the state saves it at the lane's
        end (and a vehicle put on the junction instead would no longer stop for its light). One that
        would then overlap another box (a follower close behind) stays as generated.
        ``others``: the host's boxes around the window (scene frame)."""
        w = scene.window
        polys = None            # every box, the host's after the scene's: made when a nose is over
        for i in range(len(scene)):
            (x, y), yaw = w.scene_to_world(scene.boxes[i, None, 0:2])[0], float(w.yaw_to_world(scene.boxes[i, 2]))
            start = self._edges_at(x, y, yaw)
            if start is None or start[2].internal:
                continue
            shape = np.asarray(start[2].shape, np.float64)
            u = shape[-1] - shape[-2]
            u /= max(float(np.hypot(*u)), 1e-9)
            half = 0.5 * float(scene.boxes[i, 3])
            over = float(np.dot(np.array([x + half * np.cos(yaw), y + half * np.sin(yaw)]) - shape[-1], u))
            if over <= LANE_END_MARGIN:
                continue
            back = over + LANE_END_MARGIN
            d = back * np.array([np.cos(scene.boxes[i, 2]), np.sin(scene.boxes[i, 2])])   # scene frame
            if polys is None:
                polys = box_polygons(np.concatenate([scene.boxes[:, :5], others[:, :5]]))
            moved = box_polygons(scene.boxes[i, None, :5] - [*d, 0, 0, 0])[0]
            if any(k != i and moved.intersection(p).area > OVERLAP_AREA for k, p in enumerate(polys)):
                continue
            polys[i] = moved
            scene.boxes[i, 0:2] -= d
            scene.traj[i, :, 0:2] -= d
            report.pulled_back[i] = back

    def seed(self, scene: Scene, others: tuple[np.ndarray, np.ndarray] | None = None,
             routes: list | None = None, types: list | None = None, sized: list | None = None) -> SeedReport:
        """Add every agent of ``scene``; call ``simulationStep`` and then :meth:`verify`.

        ``routes``: per agent a route (edges from where it stands) it should drive, or None: the
        vehicle of a demand it stands for (``report.own_route``: followed, rerouted to its end, or
        "lost" when neither reaches it and a destination is drawn as for the others). ``types``:
        per agent a vType it is asked to be (a token's, a demand vehicle's own), or None: with a
        demand one of the scenario's chosen by :meth:`~sumo_scendiff.sim.fleet.Fleet.assign`.
        ``sized``: per agent what its user token fixes of its size (:func:`~sumo_scendiff.sim.fleet.own_size`):
        such a vehicle has its box's size whatever vType it is.

        ``others``: (boxes (M, 5), speeds (M,)) in the scene frame of the host's vehicles around the
        window, which can be the vehicle ahead of an agent. An agent departs at its generated speed,
        or at the Krauss safe speed for the gap to the vehicle ahead when that is lower (a generated
        queue can have a moving car a metre behind a standing one; SUMO would brake it at once beyond
        its ``decel``): those are in ``report.slowed``.
        """
        report = SeedReport()
        self._placing = {}
        keep, types, gaps, depart = self._prepare(scene, others, types, report, sized)
        self._own_size = {i for i, s in enumerate(sized or ()) if s}
        self.routes.refresh()
        for i in range(len(scene)):
            if keep[i]:
                self._add(scene, i, types[i], gaps[i], depart[i], routes[i] if routes is not None else None, report)
        return report

    def _prepare(self, scene: Scene, others, types: list | None, report: SeedReport, sized: list | None = None):
        """Before any vehicle is added: each agent's vType (the scenario's, boxes resized), its
        pose fitted at red junctions and lane ends, whether it is seeded (``report.dropped`` says why
        not), its minGap and its departure speed. Returns (keep, types, min gaps, departure speeds)."""
        other_boxes, other_speed = others if others is not None else (np.zeros((0, 5)), np.zeros(0))
        types, crowded = self._known_types().assign(   # the scenario's vTypes, boxes resized (sim/fleet.py)
            scene, other_boxes, *self.leaders(np.concatenate([scene.boxes[:, :5], other_boxes[:, :5]])),
            self.net, types, self.rng, sized)
        gone = self.fit_red_junctions(scene, report, other_boxes)
        self.fit_lane_ends(scene, report, other_boxes)
        lead, bumper_gap = self.leaders(scene.boxes, other_boxes)
        gaps = self.min_gaps(bumper_gap)
        lead_speed = np.concatenate([scene.speed[:, T0], other_speed]).astype(np.float64)
        keep, hold, report.dropped = self.resolve(scene, other_boxes, other_speed)
        for i, why in {**gone, **self.on_others(scene, other_boxes), **crowded}.items():
            keep[i], hold[i] = False, False
            report.dropped[i] = why
        lead_speed[:len(scene)][hold] = 0.0      # a follower of a held agent departs safe behind it
        return keep, types, gaps, self.departure_speeds(lead, bumper_gap - gaps, lead_speed, types)

    def _add(self, scene: Scene, i: int, vtype: str | None, gap: float, depart: float, given: list | None,
             report: SeedReport) -> None:
        """Add agent ``i`` as a SUMO vehicle at its pose (recorded in ``report``: its id and target,
        or why SUMO refused it)."""
        sim, w = self.sim, scene.window
        world = w.scene_to_world(scene.traj[i, :, :2])
        yaws = np.asarray(w.yaw_to_world(scene.traj[i, :, 2]))
        fx, fy, angle = pose_to_sumo(world[T0, 0], world[T0, 1], yaws[T0], scene.boxes[i, 3])
        route = self.route_for(scene, i, world, yaws)
        if route is None:
            report.refused[i] = "no car lane at its pose"
            return
        edges, lane_index, lane, last_lane = route
        vid = f"{self.prefix}{self.count}"
        self.count += 1
        try:
            width = float(scene.boxes[i, 4])
            if self.width_cap is not None and width > self.width_cap and vtype is None:
                report.narrowed[i] = (width, self.width_cap)
                width = self.width_cap
            tid = self.vtype(scene.vclass[i], vtype)
            full, how = self.routes.along(edges, last_lane, given, tid) if given else ([], "")
            if given:
                report.own_route[i] = how or "lost"
            full = full or self.routes.complete(edges, last_lane, tid, self.rng)
            speed, slowed = max(float(scene.speed[i, T0]), 0.0), None
            # held for a foe on its junction, safe behind the one ahead, or at most what its vType
            # drives (a scenario's slow type: SUMO refuses a departure above its maxSpeed)
            cap = min(float(depart), sim.vehicletype.getMaxSpeed(tid))
            if cap < speed:
                slowed, speed = (speed, cap), cap
            self.add_on_route(vid, full, typeID=tid, depart="now",
                              departLane=str(lane_index) if not lane.internal else "best",
                              departPos=self._depart_pos(lane, full, fx, fy), departSpeed=f"{speed:.3f}")
            self.fit_type(vid, scene.boxes[i, 3], width, gap, vtype if tid == vtype else None, i in self._own_size)
            if not self.meso:
                sim.vehicle.moveToXY(vid, "" if lane.internal else lane.edge, lane.index,
                                     float(fx), float(fy), float(angle), keepRoute=self.keep_route)
        except Exception as e:  # libsumo.TraCIException / traci.TraCIException
            if type(e).__name__ == "FatalTraCIError":    # SUMO itself gone, not a refusal
                raise
            report.refused[i] = str(e).splitlines()[0] if str(e) else type(e).__name__
            self._withdraw(vid)
            return
        report.ids[i] = vid
        report.targets[i] = (float(fx), float(fy), float(angle))
        if not lane.internal:
            report.lanes[i] = (lane.id, self._front_pos(lane, fx, fy))
        self._placing[vid] = ((lane.id, min(self._front_pos(lane, fx, fy), lane.length)), tuple(full[:3]),
                              (float(fx), float(fy)))
        if slowed is not None:
            report.slowed[i] = slowed

    def _depart_pos(self, lane, edges: list[str], fx: float, fy: float) -> str:
        """``vehicle.add``'s departPos: the lane's start where ``moveToXY`` then puts the vehicle at its
        pose; in the mesoscopic model its front's place along its edge (SUMO inserts it into the segment
        holding it), or the end of the edge it leaves where it stands inside a junction (no segment)."""
        if not self.meso:
            return "base"
        length = self.net.sumo_net.getEdge(edges[0]).getLength()
        return f"{min(self._front_pos(lane, fx, fy), length) if not lane.internal else length:.3f}"

    def _front_pos(self, lane, fx: float, fy: float) -> float:
        """m along ``lane`` (a :class:`~sumo_scendiff.map.network.Lane`) of the front point (fx, fy)."""
        return float(shapely.LineString(lane.shape).project(shapely.Point(fx, fy)))

    def keep_on_seeded_lanes(self, report: SeedReport) -> None:
        """After the seeding step: a vehicle SUMO matched onto the very start of a junction's
        internal lane (its position there clamped at 0; e.g. a route that turns around, whose
        internal lane starts beside the lane) while its front stands on the normal lane it was
        seeded on is moved onto that lane at its front (``moveTo``). SUMO shows it where asked for
        the step, but would save and drive it from the internal lane's start, metres away."""
        sim = self.sim
        for i, (lane_id, pos) in report.lanes.items():
            vid = report.ids.get(i)
            try:
                if not sim.vehicle.getLaneID(vid).startswith(":") or sim.vehicle.getLanePosition(vid) > CLAMPED:
                    continue
                sim.vehicle.moveTo(vid, lane_id, pos)
            except Exception:   # gone, or the lane is not on its route: it stays as SUMO has it
                continue

    def _withdraw(self, vid: str) -> None:
        """Take back a vehicle SUMO did not take as seeded: added but refused a pose, or still waiting
        to be inserted, it would otherwise enter later, somewhere, as a vehicle no record names."""
        try:
            self.sim.vehicle.remove(vid)
        except Exception:   # never added, or already gone
            pass
        self._drop_stage(vid)

    def _back_on_road(self, vid: str) -> str | None:
        """A vehicle SUMO holds on no lane after the seeding step (``moveToXY(keepRoute=2)`` with no lane
        of its route within reach of its pose: SUMO keeps it at the exact point, off the road, and removes
        it at the next step) is put on the lane it was seeded on at its front (``moveTo``), else on the
        lane of its route's start nearest its front: None; it is then placed or misplaced as measured.
        Where SUMO takes neither: why it is not seeded. Its road is never asked for (libsumo crashes on
        getRoadID of such a vehicle)."""
        if vid not in self._placing:
            return "SUMO held it off the road (no lane of its route within reach of its pose)"
        seeded, edges, front = self._placing[vid]
        said = ""
        for lane in [seeded] + self._route_lanes(edges, *front):
            try:
                self.sim.vehicle.moveTo(vid, *lane)
                return None
            except Exception as e:   # not on its route: the next
                said = said or (str(e).splitlines()[0] if str(e) else "")
        return ("SUMO held it off the road (no lane of its route within reach of its pose"
                + (f"; and on its lane: {said})" if said else ")"))

    def _route_lanes(self, edges: tuple, fx: float, fy: float) -> list[tuple[str, float]]:
        """(lane id, m along it of the point nearest (fx, fy)) for the lanes of ``edges`` (a route's
        first edges) and of the junctions between them, nearest first."""
        net, pairs = self.net, set(zip(edges, edges[1:]))
        ids = [f"{e}_{k}" for e in edges for k in range(self.net.sumo_net.getEdge(e).getLaneNumber())]
        ids += [lane for lane, link in self._via.items() if link in pairs]
        known = np.array([net.lane_index[i] for i in dict.fromkeys(ids) if i in net.lane_index], np.int64)
        if not len(known):
            return []
        point = shapely.Point(fx, fy)
        order = known[np.argsort(shapely.distance(net.lines[known], point))]
        return [(net.lanes[k].id, float(shapely.line_locate_point(net.lines[k], point))) for k in order]

    def verify(self, report: SeedReport) -> SeedReport:
        """After a simulation step: which seeded agents are not where they were generated (those
        SUMO clamped onto a junction's start first put back on their lane, :meth:`keep_on_seeded_lanes`).
        One SUMO does not have after the step (not inserted, or removed at once) is refused, with the
        reason, and taken back: a ``placed`` or ``misplaced`` agent is a vehicle in the simulation."""
        self.keep_on_seeded_lanes(report)
        present = set(self.sim.vehicle.getIDList())
        collided = set(self.sim.simulation.getCollidingVehiclesIDList())
        for i, vid in list(report.ids.items()):
            fx, fy, angle = report.targets[i]
            why = None
            if vid not in present:
                why = ("removed by SUMO after a collision in the seeding step" if vid in collided
                       else "not in the simulation after the seeding step (SUMO did not insert it"
                       + (" into its segment, in its mesoscopic model)" if self.meso else ")"))
            elif not self.meso and not self.sim.vehicle.getLaneID(vid):
                why = self._back_on_road(vid)
            if why is not None:
                report.refused[i] = why
                self._withdraw(vid)
                for d in (report.ids, report.targets, report.lanes, report.slowed):
                    d.pop(i, None)
                continue
            x, y = self.sim.vehicle.getPosition(vid)
            err = float(np.hypot(x - fx, y - fy))
            if self.meso:     # its pose is its segment's start: placed where SUMO has it on its pose's edge
                edge = self.sim.lane.getEdgeID(report.lanes[i][0]) if i in report.lanes else None
                if self.sim.vehicle.getRoadID(vid) != edge:
                    report.misplaced[i] = err
                continue
            dyaw = abs(float(wrap_angle(np.radians(angle - self.sim.vehicle.getAngle(vid)))))
            if err > POS_TOLERANCE or dyaw > YAW_TOLERANCE:
                report.misplaced[i] = err
        return report


__all__ = ["STATUSES", "Seeder", "SeedReport", "krauss_safe_speed"]
