"""After the seeding step: seeded vehicles fitted to what SUMO itself sees ahead of them.

    report = seeder.seed(scene); sim.simulationStep(); seeder.verify(report)
    seeder.settle(report)           # minGaps that fit, none faster than it can stop

:class:`Settling` is the part of :class:`~sumo_scendiff.sim.seeding.Seeder` that runs once the
vehicles are in SUMO: against the leader SUMO reports (across junctions and sublanes), a red light,
and the links a vehicle must be ready to stop at, a seeded vehicle too close gets a minGap that fits
and one too fast is slowed to the Krauss safe speed. The Seeder gives it ``sim`` (libsumo or traci),
``junctions`` (:class:`~sumo_scendiff.sim.junctions.JunctionConflicts`) and ``junction_stops``; a
``report`` is its :class:`~sumo_scendiff.sim.seeding.SeedReport` (``ids``, ``slowed``, ``gap_fitted``).
"""
from __future__ import annotations

import numpy as np

from ..core.geometry import sumo_to_pose
from .junctions import time_to_cover

MIN_GAP_MARGIN = 0.2   # m: a seeded vehicle's minGap stays this much below its bumper gap
FOE_VISIBILITY = 4.5   # m: netconvert's default foe visibility distance of a link without priority
LINKS_AHEAD = 2        # links (a turn's entry and its internal junction) settle looks at
AT_THE_LINE = 0.5      # m: a nose this far past a red stop line is a vehicle at the line (Seeder's POS_TOLERANCE)


def krauss_safe_speed(gap: float, v_leader: float, decel: float, tau: float) -> float:
    """The fastest speed that can still stop behind a leader braking at the same ``decel``: Krauss's
    safe speed (Krauss 1998, eq. 2.12 in its ballistic form), ``v tau + v^2 / 2b <= g + v_l^2 / 2b``,
    the bound SUMO's default car-following model keeps to (``MSCFModel_Krauss::vsafe``)."""
    b = decel
    return float(-b * tau + np.sqrt((b * tau) ** 2 + v_leader ** 2 + 2.0 * b * max(gap, 0.0)))


class Settling:
    junction_leaders_on = True     # settle: foes inside the junction as leaders (junction_leaders)
    meso = False                   # SUMO's mesoscopic model (the Seeder's host): nothing to settle

    def fit_min_gap(self, i: int, vid: str, gap: float, report) -> None:
        """SUMO sees a leader ``gap`` < 0 m beyond this vehicle's minGap (``getLeader``'s distance
        counts from front bumper + minGap): SUMO registers a collision whenever a gap is below the
        follower's minGap (``--collision.mingap-factor``, default: the whole minGap), so a vehicle
        seeded that close would collide standing still. Its minGap shrinks to fit the bumper gap."""
        old = float(self.sim.vehicle.getMinGap(vid))
        new = max(old + gap - MIN_GAP_MARGIN, 0.0)
        self.sim.vehicle.setMinGap(vid, new)     # its own vType's (Seeder.fit_type): no other vehicle's
        report.gap_fitted[i] = (report.gap_fitted.get(i, (old,))[0], new)

    def link_stops(self, vid: str, reach: float = 100.0, links: int = LINKS_AHEAD) -> list[tuple[float, float]]:
        """The junctions ahead as SUMO's junction model sees them, as (gap, speed) "leaders" for the
        Krauss safe speed (``vehicle.getNextLinks``: one entry link per junction):

        * a link the vehicle must be able to stop at -- the next one closed (``isOpen`` false: red, or
          a foe it has to yield to), a red one, one without priority (``g m s w =``) while farther than
          the foe visibility distance (SUMO approaches those ready to stop and looks at its foes only
          from there), or the next one without priority while a foe approaches it (``hasFoe``: SUMO
          brakes a vehicle that cannot stop there beyond its decel) -- is a standing leader at its
          stop line;
        * a turn that waits inside the junction (an entry without priority whose internal lane ends at
          an internal junction: the left turn's waiting point) a standing leader at that point.

        (A turn's lower speed limit needs nothing: SUMO slows for it braking at most ``decel``,
        measured with SUMO 1.28.)

        A vehicle on a junction's internal lane: the links after the lane its movement leads to (a
        minor link just beyond a junction it is crossing), and if its movement is red now,
        :meth:`red_stops`."""
        sim = self.sim
        lane = sim.vehicle.getLaneID(vid)
        if not lane:
            return []
        d = float(sim.lane.getLength(lane) - sim.vehicle.getLanePosition(vid))
        out = []
        if lane.startswith(":"):
            out = self.red_stops(vid, lane)
            d = self._to_next_stop_line(lane, d)
        for k, link in enumerate(sim.vehicle.getNextLinks(vid)[:links]):
            if d > reach:
                break
            to, prio, opened, _foe, via, state = link[:6]
            if (k == 0 and not opened) or state in "rR" or (not prio and state in "gmsw=" and
                                                            (d > FOE_VISIBILITY or (k == 0 and _foe))):
                out.append((d, 0.0))
                break
            if not via:
                break
            inner = d + float(sim.lane.getLength(via))
            if not prio and any(str(x[0]).startswith(":") and not x[1] for x in sim.lane.getLinks(via)):
                out.append((inner, 0.0))      # the turn's waiting point inside the junction
                break
            d = inner + float(sim.lane.getLength(to))
        return out

    def inside(self, junction: str, cache: dict) -> list[tuple[str, str]]:
        """The vehicles (any: the host's and seeded) on ``junction``'s internal lanes now, with their
        lane; read once per settle (``cache``), and only for the junctions a seeded vehicle is in or
        drives to (a host over TraCI pays a call per lane)."""
        if junction not in cache:
            cache[junction] = [(vid, lane) for lane in self.junctions.lanes_of.get(junction, ())
                               for vid in self.sim.lane.getLastStepVehicleIDs(lane)]
        return cache[junction]

    def junction_leaders(self, vid: str, cache: dict, reach: float = 100.0) -> list[tuple[float, float]]:
        """Vehicles already inside the junction ahead (or the one this vehicle is in) on a foe link
        that will still hold the area the two links' paths share when this vehicle gets there
        (:meth:`~sumo_scendiff.sim.junctions.JunctionConflicts.occupancy`, each driving on from its
        speed at ``junctions.ACCEL``), as standing leaders at the area's start. SUMO treats a foe inside a
        junction as a leader at the conflict (``MSLink::getLeaderInfo``), also one that has
        priority and also one standing short of the area; a vehicle seeded too fast to stop there
        brakes beyond its decel or collides. ``cache``: for :meth:`inside`, one per settle.

        SUMO's own ``vehicle.getJunctionFoes`` would say this, but reports nothing for a vehicle in
        the step it was inserted in, which is when settle runs."""
        sim, jc = self.sim, self.junctions
        lane = sim.vehicle.getLaneID(vid)
        if lane in jc.link:
            path, front = lane, float(sim.vehicle.getLanePosition(vid))
        elif lane:
            links = sim.vehicle.getNextLinks(vid)[:1]
            d = float(sim.lane.getLength(lane) - sim.vehicle.getLanePosition(vid))
            if not links or not links[0][4] or links[0][4] not in jc.link or d > reach:
                return []
            path, front = links[0][4], -d
        else:
            return []
        v = max(float(sim.vehicle.getSpeed(vid)), 0.0)
        length = float(sim.vehicle.getLength(vid))
        out = []
        for other, other_lane in self.inside(jc.link[path][0], cache):
            if other == vid or not jc.foes(path, other_lane):
                continue
            area = jc.path_area(path, other_lane)
            if area is None or area[0] - front <= 0.0:
                continue
            x, y = sim.vehicle.getPosition(other)
            ol = float(sim.vehicle.getLength(other))
            cx, cy, yaw = sumo_to_pose(x, y, sim.vehicle.getAngle(other), ol)
            occ = jc.occupancy(other_lane, (cx, cy, yaw, ol), float(sim.vehicle.getSpeed(other)), path)
            if occ is None:
                continue
            if occ[0] < time_to_cover(area[1] - front + length, v) and occ[1] > time_to_cover(area[0] - front, v):
                out.append((area[0] - front, 0.0))
        return out

    def _to_next_stop_line(self, lane: str, d: float) -> float:
        """From ``d`` m before the end of internal lane ``lane``: the distance to the end of the
        normal lane its movement leads to (the stop line of the vehicle's next link), through the
        movement's later internal lanes."""
        sim = self.sim
        for _ in range(8):
            links = sim.lane.getLinks(lane)
            if not links:
                break
            to, via = links[0][0], links[0][4]
            if via:
                lane = via
                d += float(sim.lane.getLength(via))
                continue
            return d + float(sim.lane.getLength(to))
        return d

    def _link_state(self, lane_id: str) -> str:
        """The signal character (``G g r y m M s =`` ...) now of the link an internal lane belongs to."""
        inc, first = self.junctions.entry[lane_id]
        try:
            for link in self.sim.lane.getLinks(inc):
                if link[4] == first:
                    return str(link[5])
        except Exception:   # a host that cannot say: no stop
            pass
        return "?"

    def green_crossings(self, lane: str, front: float) -> list[float]:
        """How far ahead of ``front`` (m along internal lane ``lane`` and its link's lanes after it)
        each area starts that its path shares with a link of the same junction that has green now
        (``G g``)."""
        j = self.junctions.link[lane][0]
        out = []
        for other, (jo, _) in self.junctions.link.items():
            if jo != j or other == lane or self.junctions.entry[other][1] != other:
                continue
            if not self.junctions.foes(lane, other) or self._link_state(other) not in "Gg":
                continue
            area = self.junctions.path_area(lane, other)
            if area is not None and area[0] - front > 0.0:
                out.append(area[0] - front)
        return out

    def red_stops(self, vid: str, lane: str) -> list[tuple[float, float]]:
        """A vehicle inside a junction on a movement whose light is red now (the model, without the
        lights, puts some there): the start of each area its path shares with a link that has green
        (:meth:`green_crossings`) is a standing leader, if it is still ahead of the vehicle's front --
        SUMO makes it yield to that stream and otherwise brakes it beyond its decel at hand-off. One
        whose nose is within :data:`AT_THE_LINE` of the line was generated at it (the seeder's pose
        tolerance; the drawn and SUMO's geometry differ by that much): it is moved back behind the
        line and stands there."""
        if lane not in self.junctions.entry or self._link_state(lane) not in "rR":
            return []
        front = float(self.sim.vehicle.getLanePosition(vid))
        inc, first = self.junctions.entry[lane]
        if lane == first and front <= AT_THE_LINE:
            # generated at its red line, SUMO put the nose just past it: back behind the line, where
            # SUMO keeps it for the light (standing on the junction it would start into the streams)
            try:
                self.sim.vehicle.moveTo(vid, inc, float(self.sim.lane.getLength(inc)) - 0.1)
                return [(0.0, 0.0)]
            except Exception:        # a host that cannot: as any vehicle on red inside
                pass
        return [(d, 0.0) for d in self.green_crossings(lane, front)]

    def settle(self, report, reach: float = 100.0):
        """After the seeding step, against the leaders as SUMO sees them (any vehicle within ``reach``
        m along its route, across junctions and sublanes, which the scene's own leaders at :meth:`seed`
        time miss; a red light; a link it must be ready to stop at, :meth:`link_stops`): a seeded vehicle closer to its leader than its minGap gets a minGap
        that fits (:meth:`fit_min_gap`); one faster than the Krauss safe speed behind it is slowed to
        that speed (``setPreviousSpeed``: the speed it ends the seeding step with). Repeats until no
        vehicle changes, since slowing a leader can make its follower too fast."""
        if self.meso:     # SUMO's mesoscopic model: no leader, no gap, no speed of a vehicle's own to set
            return report
        sim, present = self.sim, set(self.sim.vehicle.getIDList())
        vids = [(i, v) for i, v in report.ids.items() if v in present]
        inside: dict[str, list] = {}
        for _ in range(len(vids)):
            changed = False
            for i, vid in vids:
                lead = sim.vehicle.getLeader(vid, reach)
                if lead and lead[0] and float(lead[1]) < 0.0:
                    self.fit_min_gap(i, vid, float(lead[1]), report)
                    lead = sim.vehicle.getLeader(vid, reach)
                stops = [(float(lead[1]), float(sim.vehicle.getSpeed(lead[0])))] if lead and lead[0] else []
                stops += [(float(d), 0.0) for _, _, d, state in sim.vehicle.getNextTLS(vid)[:1]
                          if state in "rR" and d < reach]        # a red light: a standing leader
                if self.junction_stops:
                    stops += self.link_stops(vid, reach)
                if self.junction_leaders_on:
                    stops += self.junction_leaders(vid, inside, reach)
                if not stops:
                    continue
                speed = float(sim.vehicle.getSpeed(vid))
                decel, tau = float(sim.vehicle.getDecel(vid)), float(sim.vehicle.getTau(vid))
                safe = min(krauss_safe_speed(g, v, decel, tau) for g, v in stops)
                if speed > safe + 1e-3:
                    sim.vehicle.setPreviousSpeed(vid, safe)
                    report.slowed[i] = (report.slowed.get(i, (speed,))[0], safe)
                    changed = True
            if not changed:
                break
        return report


__all__ = ["AT_THE_LINE", "FOE_VISIBILITY", "LINKS_AHEAD", "MIN_GAP_MARGIN", "Settling", "krauss_safe_speed"]
