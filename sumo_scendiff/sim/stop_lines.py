"""Agents the model put inside a junction on a movement whose light is red now, moved to its stop line.

    gone = seeder.fit_red_junctions(scene, report, other_boxes)   # in Seeder.seed, before the leaders

The model draws a window without the host's lights (unless ``--signals``), and about a third of the
agents it puts on a junction's internal lanes stand or creep on a movement that is red in the host
at hand-off; SUMO's own traffic has almost none there (vehicles that entered at yellow clear at
speed). Seeded as generated, SUMO drives such a vehicle on (it has passed its stop line) into the
streams that have green, or into a movement whose lanes overlap its own without being its foe (a
big junction cluster's opposite left turns), which the light never lets meet.

What the scene means there is a vehicle waiting for its light: one slower than
:data:`CLEARING_SPEED`, or one with a stream that has green still to cross ahead of its nose
(it could only wait inside the junction), is moved back onto the lane its movement comes from,
standing with its nose :data:`STOP_LINE_GAP` behind the stop line, the whole trajectory with it
(the scene records the pose, as for a nose over the line: ``report.to_stop_line``); where that
place is taken (a queue's head, a host vehicle, in the scene or in the simulation) it stands a
minGap behind the queue there, within :data:`QUEUE_REACH` m of the line, else it is not seeded
(``report.conflicts``). A faster one past every green stream is left to clear the junction as a
vehicle that entered at yellow.
"""
from __future__ import annotations

import numpy as np
import shapely

from ..core.geometry import OVERLAP_AREA, T0, box_polygons
from .fleet import DEFAULT_MIN_GAP as QUEUE_GAP   # kept between a moved vehicle and the one ahead

CLEARING_SPEED = 3.0   # m/s: slower than this on a red movement inside a junction, it is waiting
STOP_LINE_GAP = 0.1    # m: a vehicle moved to its stop line stands this far behind it
QUEUE_REACH = 60.0     # m: how far behind its stop line a moved vehicle may stand (the queue's end)


class StopLines:
    red_to_stop_line = True    # Seeder.seed: fit_red_junctions on

    def fit_red_junctions(self, scene, report, others: np.ndarray) -> dict[int, str]:
        """Move the agents waiting inside a junction on red to their stop line (module docstring).
        ``others``: the host's boxes around the window (scene frame). Returns {agent: why not
        seeded} for those whose place at the stop line is taken."""
        n = len(scene)
        self.moved_from = {}        # agent -> the internal lane it was generated on (route_for keeps its movement)
        if not self.red_to_stop_line or not n:
            return {}
        w = scene.window
        world = scene.boxes[:, :5].astype(np.float64).copy()
        world[:, :2] = w.scene_to_world(world[:, :2])
        world[:, 2] = np.asarray(w.yaw_to_world(world[:, 2]))
        polys, gone = None, {}
        for i, (x, y, yaw, length) in enumerate(world[:, :4]):
            hit = self.net.lookup(x, y, yaw)        # the centre: a nose over the line is fit_lane_ends'
            lane = hit[0].id if hit is not None and hit[0].internal else None
            if lane not in self.junctions.entry or self._link_state(lane) not in "rR":
                continue
            if float(scene.speed[i, T0]) >= CLEARING_SPEED:
                line = shapely.LineString(self.net.lanes[self.net.lane_index[lane]].shape)
                front = line.project(shapely.Point(x + 0.5 * length * np.cos(yaw), y + 0.5 * length * np.sin(yaw)))
                if not self.green_crossings(lane, front):
                    continue                        # past every green stream: it clears, as at yellow
            inc = self.junctions.entry[lane][0]
            if polys is None:
                polys = list(box_polygons(np.concatenate([scene.boxes[:, :5], others[:, :5]])))
            box = self._queue_place(inc, float(scene.boxes[i, 3]), float(scene.boxes[i, 4]), w,
                                    [p for k, p in enumerate(polys) if k != i and k not in gone])
            if box is None:
                gone[i] = f"on red inside the junction; no room within {QUEUE_REACH:g} m of its stop line"
                continue
            polys[i] = box_polygons(box[None])[0]
            report.to_stop_line[i] = float(np.hypot(*(box[:2] - scene.boxes[i, :2])))
            self.moved_from[i] = lane
            scene.boxes[i, :3] = box[:3]
            scene.traj[i, :, 0], scene.traj[i, :, 1], scene.traj[i, :, 2] = box[0], box[1], box[2]
            scene.speed[i] = 0.0
        return gone


    def _queue_place(self, lane: str, length: float, width: float, window, polys) -> np.ndarray | None:
        """The box (scene frame) of a vehicle standing at the head of the queue on ``lane``: its nose
        :data:`STOP_LINE_GAP` behind the stop line, or, where that is taken, a minGap behind the
        last vehicle there (the simulation's, seeded or not, also beyond the window; ``polys`` the
        scene's other boxes), within :data:`QUEUE_REACH` m of the line; None if there is no room."""
        sim = self.sim
        shape = self.net.lanes[self.net.lane_index[lane]].shape
        line = shapely.LineString(shape)
        scale = line.length / max(float(sim.lane.getLength(lane)), 1e-9)   # SUMO's lane positions -> shape
        taken = sorted((float(sim.vehicle.getLanePosition(v)) * scale,
                        (float(sim.vehicle.getLanePosition(v)) - float(sim.vehicle.getLength(v))) * scale)
                       for v in sim.lane.getLastStepVehicleIDs(lane))
        nose = line.length - STOP_LINE_GAP
        while nose - length >= max(line.length - QUEUE_REACH, 0.0):
            blocker = next(((f, r) for f, r in reversed(taken) if f > nose - length - QUEUE_GAP and r < nose), None)
            if blocker is None:
                c = line.interpolate(nose - 0.5 * length)
                q = line.interpolate(min(nose - 0.5 * length + 0.5, line.length))
                yaw = np.arctan2(q.y - c.y, q.x - c.x)
                xy = window.world_to_scene(np.array([[c.x, c.y]]))[0]
                box = np.array([xy[0], xy[1], float(window.yaw_to_scene(yaw)), length, width])
                mine = box_polygons(box[None])[0]
                clash = [p for p in polys if mine.intersection(p).area > OVERLAP_AREA]
                if not clash:
                    return box
                # behind the scene's box it overlaps: its rear along the lane, then a minGap
                rear = min(line.project(shapely.Point(xy_w)) for p in clash
                           for xy_w in window.scene_to_world(np.asarray(p.exterior.coords)[:, :2]))
                nose = min(nose - 0.5, rear - QUEUE_GAP)
            else:
                nose = blocker[1] - QUEUE_GAP
        return None


__all__ = ["CLEARING_SPEED", "QUEUE_REACH", "STOP_LINE_GAP", "StopLines"]
