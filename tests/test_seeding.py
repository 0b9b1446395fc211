"""Seeder: generated agents become SUMO vehicles at their generated poses (real libsumo)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_scendiff.geometry import Window
from sumo_scendiff.network import Network
from sumo_scendiff.scene import Scene
from sumo_scendiff.seeding import Seeder


def scene_on(net: Network) -> Scene:
    """Five agents: a queue of two (1 m bumper gap) eastbound, one northbound, one in the junction
    turning, one off the road (refused)."""
    east = next(ln for ln in net.lanes if ln.edge == "wc")
    north = next(ln for ln in net.lanes if ln.edge == "sc")
    turn = next(ln for ln in net.lanes if ln.internal and ln.car and len(ln.shape) > 3)
    ye, xn = float(east.shape[0][1]), float(north.shape[0][0])
    mid = len(turn.shape) // 2
    d = turn.shape[mid + 1] - turn.shape[mid]
    tyaw = math.atan2(d[1], d[0])
    boxes = [[-60.0, ye, 0.0, 4.6, 1.8], [-65.6, ye, 0.0, 4.6, 1.8], [xn, -80.0, math.pi / 2, 5.1, 1.95],
             [*turn.shape[mid], tyaw, 4.6, 1.8], [-60.0, -40.0, 0.0, 4.6, 1.8]]
    speeds = [0.0, 0.0, 8.0, 3.0, 5.0]
    boxes = np.array(boxes)
    traj = np.zeros((5, 5, 3))
    for i, (x, y, yaw, _, _) in enumerate(boxes):
        for k, t in enumerate(range(-2, 3)):
            traj[i, k] = (x + speeds[i] * t * math.cos(yaw), y + speeds[i] * t * math.sin(yaw), yaw)
    mask = np.ones((5, 5), bool)
    mask[3, 3:] = False  # the turning agent's future unknown
    return Scene(Window(0.0, 0.0, 0.0), boxes, traj, mask, np.repeat(np.array(speeds)[:, None], 5, 1),
                 np.zeros(5), "cross")


def test_seeded_vehicles_stand_where_generated(cross_net):
    import libsumo as sim
    net = Network.load(cross_net)
    scene = scene_on(net)
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings", "--collision.check-junctions"])
    try:
        seeder = Seeder(sim, net)
        report = seeder.seed(scene)
        assert set(report.refused) == {4} and "no car lane" in report.refused[4]
        sim.simulationStep()
        report = seeder.verify(report)
        assert report.placed == 4 and not report.misplaced
        for i, vid in report.ids.items():
            assert sim.vehicle.getLength(vid) == pytest.approx(scene.boxes[i, 3])
            route = sim.vehicle.getRoute(vid)
            assert not route[0].startswith(":") and len(route) >= 2
        assert sim.vehicletype.getMinGap(sim.vehicle.getTypeID(report.ids[1])) < 1.0  # fits the queue
        assert sim.vehicle.getSpeed(report.ids[2]) == pytest.approx(8.0, abs=1.0)
        for _ in range(5):
            sim.simulationStep()
        assert sim.simulation.getCollidingVehiclesNumber() == 0
    finally:
        sim.close()
