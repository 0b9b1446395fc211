"""What SUMO drives from a folder's start: its ``scenario.sumocfg`` (the saved state) run in libsumo
for the rollout's seconds, box-centre poses at every step, and each vehicle's type as SUMO has it.

A folder holds no FCD of its rollout, so the path is the one stock SUMO drives from the folder
(``sumo -c scenario.sumocfg``, the configuration's seed): what a user replaying the folder sees.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..core.geometry import sumo_to_pose
from ..sim.sumo import SimError, close, start_config
from .opendrive import ExportError


@dataclass
class VehicleType:
    vclass: str
    length: float
    width: float
    height: float
    max_speed: float
    accel: float
    decel: float


@dataclass
class Replay:
    begin: float                                   # SUMO's time of the start (the scene's t = 0)
    step: float
    types: dict[str, VehicleType] = field(default_factory=dict)   # vehicle id -> its type
    # vehicle id -> [(t since the start, x, y, yaw, speed)], box centres
    paths: dict[str, list[tuple[float, float, float, float, float]]] = field(default_factory=dict)


def _type(sim, vid: str) -> VehicleType:
    t, vt = sim.vehicle.getTypeID(vid), sim.vehicletype
    return VehicleType(vt.getVehicleClass(t), vt.getLength(t), vt.getWidth(t), vt.getHeight(t),
                       min(vt.getMaxSpeed(t), sim.vehicle.getMaxSpeed(vid)), vt.getAccel(t), vt.getDecel(t))


def replay(config: str, ids: list[str], seconds: float) -> Replay:
    """Run ``config`` for ``seconds`` recording vehicles ``ids`` (those present at the start)."""
    try:
        sim = start_config(config)
    except SimError as e:
        raise ExportError(f"{config}: {e}") from None
    try:
        present = set(sim.vehicle.getIDList())
        want = [v for v in ids if v in present]
        out = Replay(begin=float(sim.simulation.getTime()), step=float(sim.simulation.getDeltaT()))
        out.types = {v: _type(sim, v) for v in want}
        out.paths = {v: [] for v in want}
        steps = int(round(seconds / out.step))
        for k in range(steps + 1):
            if k:
                sim.simulationStep()
            t = round(float(sim.simulation.getTime()) - out.begin, 6)
            here = set(sim.vehicle.getIDList())
            for v in want:
                if v in here:
                    x, y = sim.vehicle.getPosition(v)
                    cx, cy, yaw = sumo_to_pose(x, y, sim.vehicle.getAngle(v), out.types[v].length)
                    out.paths[v].append((t, float(cx), float(cy), float(yaw), float(sim.vehicle.getSpeed(v))))
    finally:
        close(sim)
    return out
