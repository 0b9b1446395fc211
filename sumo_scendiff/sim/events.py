"""Hand-off events in detail: who collided where, with which right of way, and how the agents were
seeded (for finding the causes of the seeding benchmark's collisions and teleports).

    tracer = EventTracer(sim, net, agents, seeded={vid: {...}})
    stats = rollout(sim, agents, 60, tracer=tracer)       # tracer.events: one dict per event

Every step the tracer keeps the last ``HISTORY`` (lane, position, speed) of every vehicle, so an
event shows how both parties got there; at an event it reads both parties' lanes, speeds and the
links they use (state: the traffic light's or the junction's ``G g r y s = m M``, whether the link
has priority, is open, has foes).
"""
from __future__ import annotations

from collections import deque

HISTORY = 16


def via_map(snet) -> dict[str, tuple[str, str, str]]:
    """Internal lane -> (incoming lane, first internal lane of its connection, outgoing lane)."""
    out: dict[str, tuple[str, str, str]] = {}
    for edge in snet.getEdges(withInternal=False):
        for lane in edge.getLanes():
            for c in lane.getOutgoing():
                via, seen = c.getViaLaneID(), 0
                first = via
                while via and seen < 8:
                    out[via] = (lane.getID(), first, c.getToLane().getID())
                    nxt = [x.getViaLaneID() or x.getToLane().getID() for x in snet.getLane(via).getOutgoing()] \
                        if snet.hasEdge(via.rsplit("_", 1)[0]) else []
                    via = next((n for n in nxt if n.startswith(":")), "")
                    seen += 1
    return out


class EventTracer:
    def __init__(self, sim, net, agents, seeded: dict | None = None, label: dict | None = None):
        self.sim, self.net, self.agents = sim, net, set(agents)
        self.seeded = seeded or {}
        self.label = label or {}
        self.hist: dict[str, deque] = {}
        self.events: list[dict] = []
        self.others: list[tuple] = []      # collisions among host vehicles only: (t, collider, victim, lane)
        self.via = via_map(net.sumo_net)
        self.t = 0.0

    def step(self, t: float) -> None:
        """After a step: remember every vehicle's lane, position, speed."""
        self.t = t
        v = self.sim.vehicle
        for vid in v.getIDList():
            d = self.hist.get(vid)
            if d is None:
                d = self.hist[vid] = deque(maxlen=HISTORY)
            d.append((round(t, 2), v.getLaneID(vid), round(v.getLanePosition(vid), 2), round(v.getSpeed(vid), 2),
                      round(v.getLateralLanePosition(vid), 2)))

    def link_of(self, lane: str) -> dict | None:
        """The link whose internal lane ``lane`` is: incoming lane, state, priority, open, foes."""
        got = self.via.get(lane)
        if got is None:
            return None
        inc, first, out = got
        try:
            for ln in self.sim.lane.getLinks(inc):
                if ln[4] == first or (not ln[4] and ln[0] == out):
                    return {"from": inc, "to": ln[0], "prio": bool(ln[1]), "open": bool(ln[2]), "foe": bool(ln[3]),
                            "state": ln[5], "dir": ln[6]}
        except Exception:
            return None
        return {"from": inc, "to": out}

    def party(self, vid: str) -> dict:
        v = self.sim.vehicle
        d = {"id": vid, "agent": vid in self.agents, "seed": self.seeded.get(vid),
             "hist": list(self.hist.get(vid, ()))}
        try:
            lane = v.getLaneID(vid)
            d.update(lane=lane, pos=v.getLanePosition(vid), speed=v.getSpeed(vid), wait=v.getWaitingTime(vid),
                     type=v.getTypeID(vid), length=v.getLength(vid),
                     width=v.getWidth(vid), lat=v.getLateralLanePosition(vid), vclass=v.getVehicleClass(vid))
            lanes = [lane] + [h[1] for h in reversed(d["hist"])]
            internal = next((x for x in lanes if x.startswith(":")), None)
            if internal:
                d["link"] = self.link_of(internal)
            nl = v.getNextLinks(vid)
            if nl:
                x = nl[0]
                d["next_link"] = {"to": x[0], "via": x[4], "prio": bool(x[1]), "open": bool(x[2]), "foe": bool(x[3]),
                                  "state": x[5], "dir": x[6]}
        except Exception as e:
            d["gone"] = str(e)[:80]
        return d

    def collision(self, c) -> None:
        ev = {"kind": "collision", "t": self.t, "lane": c.lane, "pos": c.pos, "type": c.type,
              "collider": self.party(c.collider), "victim": self.party(c.victim),
              "collider_speed": c.colliderSpeed, "victim_speed": c.victimSpeed, **self.label}
        self.events.append(ev)

    def brake(self, vid: str, accel: float, t: float) -> None:
        """An agent braking beyond its decel (first time in the brake window): it and its leader."""
        d = {"kind": "brake", "t": t, "accel": accel, "who": self.party(vid), **self.label}
        try:
            lead = self.sim.vehicle.getLeader(vid, 100.0)
            if lead and lead[0]:
                d["leader"] = self.party(lead[0])
                d["gap"] = lead[1]
            d["tls"] = [(x[0], x[2], x[3]) for x in self.sim.vehicle.getNextTLS(vid)[:1]]
            d["decel"] = self.sim.vehicle.getDecel(vid)
        except Exception:
            pass
        self.events.append(d)

    def teleport(self, vid: str) -> None:
        self.events.append({"kind": "teleport", "t": self.t, "who": self.party(vid), **self.label})


def seed_info(sim, report, scene) -> dict[str, dict]:
    """Per seeded vehicle, how it stands after the seeding step: its lane, distance to the lane's end
    (the stop line on an approach), speed, the next link's state and priority, held / slowed."""
    from ..core.geometry import T0
    out = {}
    v = sim.vehicle
    present = set(v.getIDList())
    for i, vid in report.ids.items():
        d = {"index": i, "gen_speed": float(scene.speed[i, T0]), "slowed": report.slowed.get(i)}
        if vid in present:
            lane = v.getLaneID(vid)
            d.update(lane=lane, internal=lane.startswith(":"), pos=v.getLanePosition(vid),
                     to_end=sim.lane.getLength(lane) - v.getLanePosition(vid), speed=v.getSpeed(vid),
                     route=list(v.getRoute(vid)))
            nl = v.getNextLinks(vid)
            if nl:
                x = nl[0]
                d["next_link"] = {"to": x[0], "via": x[4], "prio": bool(x[1]), "open": bool(x[2]), "foe": bool(x[3]),
                                  "state": x[5], "dir": x[6]}
        out[vid] = d
    return out


__all__ = ["EventTracer", "seed_info", "via_map"]
