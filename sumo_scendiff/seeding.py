"""Seeder: generated agents -> real SUMO vehicles at their generated poses (libsumo or traci).

    import libsumo as sim                      # or traci, connected to sumo / sumo-gui
    seeder = Seeder(sim, net)
    report = seeder.seed(scene)                # vehicle.add + vehicle.moveToXY(keepRoute=1) per agent
    sim.simulationStep()
    report = seeder.verify(report)             # who stands where it was generated (0.5 m, 0.1 rad)

For each agent:
the lane it stands on (heading agreement; an internal junction lane gives the route its incoming
and outgoing edges, never starts a route), a route through the lanes of its +1/+2 s poses and on
along the network (no u-turns) to a fringe or 30 edges, a vehicle type with its box and a minGap that
fits the gap to the vehicle ahead in the scene, then ``vehicle.add`` and ``vehicle.moveToXY``. SUMO
refusing a vehicle never crashes the host simulation: the agent is reported as refused.

Generated agents are rarely on a lane's centre line. With SUMO's sublane model
(``--lateral-resolution``, which :mod:`~sumo_scendiff.sumo_sim` turns on) ``moveToXY`` with
``keepRoute=1`` keeps their lateral offset; without it SUMO snaps them to the centre line (measured
on city.net.xml: 73 of 96 generated agents then off by 0.5-4 m), so the Seeder uses ``keepRoute=2``
(exact pose, mapped to the nearest lane of its route) in such host simulations.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import T0, pose_to_sumo, wrap_angle
from .network import Network
from .scene import VEHICLE_CLASSES, Scene

POS_TOLERANCE, YAW_TOLERANCE = 0.5, 0.1   # m, rad: "present where it was generated"
MAX_ROUTE_EDGES = 30
DEFAULT_MIN_GAP = 2.5


@dataclass
class SeedReport:
    ids: dict[int, str] = field(default_factory=dict)        # agent index -> vehicle id
    refused: dict[int, str] = field(default_factory=dict)    # agent index -> reason
    misplaced: dict[int, float] = field(default_factory=dict)  # agent index -> position error (m)
    targets: dict[int, tuple] = field(default_factory=dict)  # agent index -> (x_front, y_front, angle)

    @property
    def placed(self) -> int:
        return len(self.ids) - len(self.misplaced)


def sublane(sim) -> bool:
    """Whether the host simulation runs SUMO's sublane model (``--lateral-resolution`` > 0)."""
    try:
        return float(sim.simulation.getOption("lateral-resolution")) > 0
    except Exception:  # SUMO < 1.19 has no getOption
        return False


class Seeder:
    def __init__(self, sim, net: Network, prefix: str = "sd", seed: int = 0):
        self.sim, self.net, self.prefix = sim, net, prefix
        self.rng = np.random.default_rng(seed)
        self.count = 0
        self._via = self._internal_links()
        self.keep_route = 1 if sublane(sim) else 2

    # ---- network helpers --------------------------------------------------------------------
    def _internal_links(self) -> dict[str, tuple[str, str]]:
        """Internal lane id -> (incoming edge, outgoing edge) of the connection it belongs to."""
        out: dict[str, tuple[str, str]] = {}
        snet = self.net.sumo_net
        for edge in snet.getEdges(withInternal=False):
            for conns in edge.getOutgoing().values():
                for c in conns:
                    lane_id = c.getViaLaneID()
                    seen = 0
                    while lane_id and seen < 8:  # follow chains of internal lanes
                        out[lane_id] = (c.getFrom().getID(), c.getTo().getID())
                        nxt = [x.getViaLaneID() or x.getToLane().getID()
                               for x in snet.getLane(lane_id).getOutgoing()] if snet.hasEdge(
                            lane_id.rsplit("_", 1)[0]) else []
                        lane_id = next((n for n in nxt if n.startswith(":")), "")
                        seen += 1
        return out

    def _edges_at(self, x: float, y: float, yaw: float) -> tuple | None:
        """(route edges for this pose, lane index on the first edge, lane) or None."""
        hit = self.net.lookup(x, y, yaw)
        if hit is None:
            return None
        lane = hit[0]
        if lane.internal:
            link = self._via.get(lane.id)
            return None if link is None else (list(link), 0, lane)
        return [lane.edge], lane.index, lane

    def _extend(self, edges: list[str]) -> list[str]:
        """Continue along the network from the last edge: random successor, no u-turns."""
        snet = self.net.sumo_net
        while len(edges) < MAX_ROUTE_EDGES:
            last = snet.getEdge(edges[-1])
            back = last.getFromNode().getID()
            succ = [e for e, conns in sorted(last.getOutgoing().items(), key=lambda kv: kv[0].getID())
                    if e.allows("passenger") and e.getToNode().getID() != back
                    and any(c.allows("passenger") for c in conns)]
            if not succ:
                break
            edges.append(succ[int(self.rng.integers(len(succ)))].getID())
        return edges

    def route_for(self, scene: Scene, i: int, world: np.ndarray, yaws: np.ndarray):
        """Edges for agent ``i``: its lane now, the lanes of its observed future poses, then onwards."""
        start = self._edges_at(world[T0, 0], world[T0, 1], yaws[T0])
        if start is None:
            return None
        edges, lane_index, lane = start
        snet = self.net.sumo_net
        for k in range(T0 + 1, len(yaws)):
            if not scene.traj_mask[i, k]:
                continue
            nxt = self._edges_at(world[k, 0], world[k, 1], yaws[k])
            for e in (nxt[0] if nxt else []):
                if e != edges[-1] and snet.getEdge(e) in snet.getEdge(edges[-1]).getOutgoing():
                    edges.append(e)
        return self._extend(edges), lane_index, lane

    # ---- vehicle types ------------------------------------------------------------------------
    def vtype(self, vid: str, length: float, width: float, vclass: int, min_gap: float) -> str:
        t = self.sim.vehicletype
        tid = f"{vid}_type"
        t.copy("DEFAULT_VEHTYPE", tid)
        t.setVehicleClass(tid, VEHICLE_CLASSES[int(vclass)])
        t.setLength(tid, float(length))
        t.setWidth(tid, float(width))
        t.setMinGap(tid, float(min_gap))
        return tid

    @staticmethod
    def min_gaps(scene: Scene) -> np.ndarray:
        """Per agent, a minGap that fits the bumper gap to the nearest agent ahead in its lane."""
        n = len(scene)
        gaps = np.full(n, DEFAULT_MIN_GAP)
        b = scene.boxes.astype(np.float64)
        for i in range(n):
            d = b[:, :2] - b[i, :2]
            c, s = np.cos(b[i, 2]), np.sin(b[i, 2])
            ahead, side = d @ [c, s], d @ [-s, c]
            same = (ahead > 0) & (np.abs(side) < 1.5) & (np.abs(wrap_angle(b[:, 2] - b[i, 2])) < 0.5)
            same[i] = False
            if same.any():
                j = np.flatnonzero(same)[np.argmin(ahead[same])]
                bumper_gap = ahead[j] - 0.5 * (b[i, 3] + b[j, 3])
                gaps[i] = float(np.clip(bumper_gap - 0.2, 0.3, DEFAULT_MIN_GAP))
        return gaps

    # ---- seeding --------------------------------------------------------------------------------
    def seed(self, scene: Scene) -> SeedReport:
        """Add every agent of ``scene``; call ``simulationStep`` and then :meth:`verify`."""
        sim, report = self.sim, SeedReport()
        w = scene.window
        gaps = self.min_gaps(scene)
        for i in range(len(scene)):
            world = w.scene_to_world(scene.traj[i, :, :2])
            yaws = np.asarray(w.yaw_to_world(scene.traj[i, :, 2]))
            fx, fy, angle = pose_to_sumo(world[T0, 0], world[T0, 1], yaws[T0], scene.boxes[i, 3])
            route = self.route_for(scene, i, world, yaws)
            if route is None:
                report.refused[i] = "no car lane at its pose"
                continue
            edges, lane_index, lane = route
            vid = f"{self.prefix}{self.count}"
            self.count += 1
            try:
                sim.route.add(f"{vid}_route", edges)
                tid = self.vtype(vid, scene.boxes[i, 3], scene.boxes[i, 4], scene.vclass[i], gaps[i])
                sim.vehicle.add(vid, f"{vid}_route", typeID=tid, depart="now",
                                departLane=str(lane_index) if not lane.internal else "best",
                                departPos="base", departSpeed=f"{max(float(scene.speed[i, T0]), 0.0):.3f}")
                sim.vehicle.moveToXY(vid, "" if lane.internal else lane.edge, lane.index,
                                     float(fx), float(fy), float(angle), keepRoute=self.keep_route)
            except Exception as e:  # libsumo.TraCIException / traci.TraCIException
                report.refused[i] = str(e).splitlines()[0] if str(e) else type(e).__name__
                continue
            report.ids[i] = vid
            report.targets[i] = (float(fx), float(fy), float(angle))
        return report

    def verify(self, report: SeedReport) -> SeedReport:
        """After a simulation step: which seeded agents are not where they were generated."""
        present = set(self.sim.vehicle.getIDList())
        for i, vid in report.ids.items():
            fx, fy, angle = report.targets[i]
            if vid not in present:
                report.misplaced[i] = float("inf")
                continue
            x, y = self.sim.vehicle.getPosition(vid)
            err = float(np.hypot(x - fx, y - fy))
            dyaw = abs(float(wrap_angle(np.radians(angle - self.sim.vehicle.getAngle(vid)))))
            if err > POS_TOLERANCE or dyaw > YAW_TOLERANCE:
                report.misplaced[i] = err
        return report


__all__ = ["Seeder", "SeedReport"]
