"""Agents the seeder does not seed, and why (``report.dropped``), decided before any is added.

    keep, hold, why = seeder.resolve(scene, other_boxes, other_speed)   # in Seeder._prepare
    why.update(Seeder.on_others(scene, other_boxes))

:class:`Drops` is the part of :class:`~sumo_scendiff.sim.seeding.Seeder` that applies its rules:
agents on internal lanes of one junction whose links conflict
(:class:`~sumo_scendiff.sim.junctions.JunctionConflicts`: of two already in the area their links
share one is kept, the later of two still before it departs standing), an agent facing a vehicle on
a lane both directions share (SUMO lets no vehicle onto it while an oncoming one is on it), and an
agent whose box overlaps a vehicle seeded before. The Seeder gives it ``net``, ``junctions`` and
``resolve_junctions``.
"""
from __future__ import annotations

import numpy as np
import shapely

from ..core.geometry import OVERLAP_AREA, T0, box_polygons
from ..core.scene import Scene


class Drops:
    def junction_lanes(self, scene: Scene, boxes: np.ndarray) -> list[str | None]:
        """Per box (world frame), the internal lane its front bumper or centre stands on, else None:
        SUMO puts a vehicle by its front bumper, so a car whose nose is past the stop line is on
        the junction."""
        out = []
        for x, y, yaw, length in boxes[:, :4]:
            lane = None
            for d in (0.5 * length, 0.0):
                hit = self.net.lookup(x + d * np.cos(yaw), y + d * np.sin(yaw), yaw)
                if hit is not None and hit[0].internal and hit[0].id in self.junctions.link:
                    lane = hit[0].id
                    break
            out.append(lane)
        return out

    def resolve(self, scene: Scene, others: np.ndarray, other_speed=None) -> tuple[np.ndarray, np.ndarray, dict]:
        """(keep, hold, why dropped) for agents on conflicting internal lanes of one junction
        (:class:`~sumo_scendiff.sim.junctions.JunctionConflicts`): of two in their shared area one is
        kept, the later of two still before it departs standing; and for agents facing a vehicle on
        a lane both directions share (:meth:`facing_on_shared_lanes`). ``others`` the host's boxes
        (scene frame), which are never dropped (their speeds: ``other_speed``)."""
        n = len(scene)
        if not self.resolve_junctions or not n:
            return np.ones(n, bool), np.zeros(n, bool), {}
        w = scene.window

        def world(b):
            b = np.asarray(b, np.float64).reshape(-1, 5).copy()
            if len(b):
                b[:, :2] = w.scene_to_world(b[:, :2])
                b[:, 2] = np.asarray(w.yaw_to_world(b[:, 2]))
            return b
        agents, hosts = world(scene.boxes[:, :5]), world(others)
        score = scene.meta.get("score")
        score = np.asarray(score, np.float64) if score is not None and len(score) == n else None
        keep, hold, why = np.ones(n, bool), np.zeros(n, bool), {}
        lanes = self.junction_lanes(scene, agents)
        if any(lanes):
            other_speed = np.zeros(len(hosts)) if other_speed is None else np.asarray(other_speed, np.float64)
            fixed = [(ln, b, v) for ln, b, v in zip(self.junction_lanes(scene, hosts), hosts, other_speed) if ln]
            keep, hold = self.junctions.resolve(lanes, agents, scene.speed[:, T0].astype(np.float64), score, fixed)
            why = {int(i): f"on junction {self.junctions.link[lanes[i]][0]}: in the area its link "
                           f"shares with another vehicle's" for i in np.flatnonzero(~keep)}
        for i, lane in self.facing_on_shared_lanes(agents, hosts, keep, score).items():
            keep[i] = False
            why[i] = f"on lane {lane}, which both directions share, facing a vehicle on it"
        return keep, hold & keep, why

    def facing_on_shared_lanes(self, agents: np.ndarray, hosts: np.ndarray, keep: np.ndarray,
                               score: np.ndarray | None) -> dict[int, str]:
        """The kept agents (world boxes ``agents``) to drop because a lane both directions share
        (:attr:`Network.shared_lanes`) holds a vehicle the other way: a host (``hosts``, never
        dropped) or a more probable agent. SUMO lets no vehicle onto such a lane while an oncoming
        one is on it; two seeded face to face on it collide in the first step."""
        shared = self.net.shared_lanes
        if not shared or not keep.any():
            return {}
        def lanes_of(b):
            if not len(b):
                return np.zeros(0, np.int64)
            return self.net.match_poses(b[:, :2], b[:, 2], allow_internal=False).lane
        on, host = lanes_of(agents), {int(ln) for ln in lanes_of(hosts) if int(ln) in shared}
        score = np.zeros(len(agents)) if score is None else score
        taken = {shared[ln] for ln in host}      # the lanes' other direction, held by a host
        out: dict[int, str] = {}
        for i in sorted(np.flatnonzero(keep), key=lambda i: (-score[i], i)):
            lane = int(on[i])
            if lane not in shared:
                continue
            if lane in taken:
                out[int(i)] = self.net.lanes[lane].id
            else:
                taken.add(shared[lane])
        return out

    @staticmethod
    def on_others(scene: Scene, others: np.ndarray) -> dict[int, str]:
        """Agents whose box overlaps one of ``others`` (scene frame), not to be seeded: a window is
        drawn around the vehicles already there, but one of those the seeder moved before (a nose
        pulled back over the stop line, a car sent from inside a junction to its stop line) may now
        stand where this window drew an agent."""
        if not len(scene) or not len(others):
            return {}
        agents, hosts = box_polygons(scene.boxes[:, :5]), box_polygons(np.asarray(others)[:, :5])
        i, j = shapely.STRtree(hosts).query(agents, predicate="intersects")
        hit = {int(a) for a, b in zip(i, j) if shapely.area(shapely.intersection(agents[a], hosts[b])) > OVERLAP_AREA}
        return {a: "its box overlaps a vehicle seeded before" for a in sorted(hit)}


__all__ = ["Drops"]
