"""Hand-off rollouts: after seeding, SUMO drives; count what happens to the seeded agents.

    stats = rollout(sim, agent_ids, seconds=60)          # sim: libsumo or traci, already seeded
    stats.per_100("collisions")

Definitions (the same for generated agents, baselines and SUMO's own traffic, see
``benchmarks/seeding.py``): a *collision* is a SUMO collision event whose collider or victim is an
agent (``--collision.check-junctions`` on); a *teleport* is an agent starting a teleport (jam,
collision or wrong lane); an *emergency brake* is an agent decelerating harder than its vehicle
type's ``decel`` (SUMO's own "emergency braking" warning threshold) — counted as agents that did so
at least once within ``brake_window`` seconds after hand-off, and as agent-steps over the whole
rollout. Collisions are also broken down by where and with whom: on a junction (an internal lane),
with a host vehicle (the other party is not an agent), a host vehicle running into an agent (SUMO's
collider is the follower), and within ``brake_window`` seconds of hand-off. Beside them, every
collision in the whole simulation and every vehicle in it (``network_*``): the host's own junction
collisions, the yardstick for a window's few agents.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from .fleet import DEFAULT_DECEL

BRAKE_MARGIN = 0.05  # m/s^2 above decel before a deceleration counts as emergency braking


@dataclass
class RolloutStats:
    seconds: float = 0.0
    agents: int = 0                  # seeded agents handed to SUMO
    collisions: int = 0
    collisions_junction: int = 0     # on an internal (junction) lane
    collisions_host: int = 0         # the other party is a host vehicle, not an agent
    collisions_host_behind: int = 0  # a host vehicle ran into an agent
    collisions_early: int = 0        # within brake_window seconds of hand-off
    teleports: int = 0
    emergency_brakes: int = 0        # agents braking beyond decel in the first brake_window seconds
    emergency_brake_steps: int = 0   # agent-steps braking beyond decel, whole rollout
    brake_window: float = 10.0
    mean_speed: float = 0.0          # m/s over agent-steps
    present_at_end: int = 0
    arrived: int = 0                 # agents that reached the end of their route
    network_collisions: int = 0      # every collision in the simulation, agents or not
    network_vehicles: int = 0        # every vehicle in the simulation during the rollout

    def per_100(self, name: str) -> float:
        return 100.0 * getattr(self, name) / max(self.agents, 1)

    def as_dict(self) -> dict:
        d = asdict(self)
        for k in ("collisions", "teleports", "emergency_brakes"):
            d[k + "_per_100"] = round(self.per_100(k), 3)
        return d


def rollout(sim, agent_ids, seconds: float, brake_window: float = 10.0,
            progress: bool = False, tracer=None) -> RolloutStats:
    """Step ``sim`` for ``seconds`` and count events involving ``agent_ids``; ``tracer``
    (:class:`~sumo_scendiff.sim.events.EventTracer`) records each event in detail."""
    ids = set(agent_ids)
    stats = RolloutStats(seconds=seconds, agents=len(ids), brake_window=brake_window)
    dt = float(sim.simulation.getDeltaT())
    steps = int(round(seconds / dt))
    present = set(sim.vehicle.getIDList())
    decel = {v: float(sim.vehicle.getDecel(v)) for v in ids & present}
    braked: set[str] = set()
    seen: set[str] = set(present)
    speeds: list[float] = []
    from tqdm import tqdm
    for k in tqdm(range(steps), disable=not progress, desc="rollout", leave=False):
        sim.simulationStep()
        if tracer is not None:
            tracer.t = (k + 1) * dt
        seen.update(sim.vehicle.getIDList())
        for c in sim.simulation.getCollisions():
            stats.network_collisions += 1
            if tracer is not None and not (c.collider in ids or c.victim in ids):
                tracer.others.append(((k + 1) * dt, c.collider, c.victim, c.lane))
            if c.collider in ids or c.victim in ids:
                if tracer is not None:
                    tracer.collision(c)
                stats.collisions += 1
                stats.collisions_junction += str(c.lane).startswith(":")
                stats.collisions_host += not (c.collider in ids and c.victim in ids)
                stats.collisions_host_behind += c.collider not in ids
                stats.collisions_early += (k + 1) * dt <= brake_window
        stats.teleports += len(ids.intersection(sim.simulation.getStartingTeleportIDList()))
        if tracer is not None:
            for v in sorted(ids.intersection(sim.simulation.getStartingTeleportIDList())):
                tracer.teleport(v)
            tracer.step((k + 1) * dt)
        stats.arrived += len(ids.intersection(sim.simulation.getArrivedIDList()))
        for v in [v for v in sim.vehicle.getIDList() if v in ids]:   # SUMO's order: reproducible
            a = float(sim.vehicle.getAcceleration(v))
            speeds.append(float(sim.vehicle.getSpeed(v)))
            if a < -(decel.get(v, DEFAULT_DECEL) + BRAKE_MARGIN):
                stats.emergency_brake_steps += 1
                if (k + 1) * dt <= brake_window:
                    if tracer is not None and v not in braked:
                        tracer.brake(v, a, (k + 1) * dt)
                    braked.add(v)
    stats.emergency_brakes = len(braked)
    stats.mean_speed = math.fsum(speeds) / len(speeds) if speeds else 0.0
    stats.present_at_end = len(ids.intersection(sim.vehicle.getIDList()))
    stats.network_vehicles = len(seen)
    return stats
