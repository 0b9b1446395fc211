"""Seeder: generated agents become SUMO vehicles at their generated poses (real libsumo)."""
from __future__ import annotations

import pytest

from sumo_scendiff.network import Network
from sumo_scendiff.seeding import Seeder


def test_seeded_vehicles_stand_where_generated(cross_net, cross_scene):
    import libsumo as sim
    net = Network.load(cross_net)
    scene = cross_scene(net)
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
