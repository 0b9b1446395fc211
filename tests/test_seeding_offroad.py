"""A pose SUMO cannot keep on a lane (sim/seeding.py): inside a junction with one connection, a few
metres beside its internal lane, ``moveToXY(keepRoute=2)`` holds the vehicle at the exact point on no
lane and SUMO removes it at the next step. The seeder puts it on that lane; it is never ``placed`` off it."""
from __future__ import annotations

import math

import pytest

from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.seeding import Seeder

from .conftest import netconvert
from .test_seeding_junctions import standing


def _bend(path: str) -> str:
    """ab east then bc north: one junction, one connection, one internal lane (a 90 degree bend)."""
    return netconvert('<node id="a" x="0" y="0"/><node id="b" x="100" y="0"/><node id="c" x="100" y="100"/>',
                      '<edge id="ab" from="a" to="b" numLanes="1" speed="13.9"/>'
                      '<edge id="bc" from="b" to="c" numLanes="1" speed="13.9"/>', path)


def test_a_vehicle_held_off_the_road_is_put_on_its_lane_not_recorded_placed(tmp_path):
    import libsumo as sim
    import numpy as np
    net_path = _bend(str(tmp_path / "bend.net.xml"))
    net = Network.load(net_path)
    inner = next(ln for ln in net.lanes if ln.internal)
    mx, my = (float(v) for v in inner.shape[len(inner.shape) // 2])
    yaw = math.pi / 4                                     # heading north-east, along the bend
    fx, fy = mx + 2.0, my - 2.0                           # its front 2.8 m outside the bend
    boxes = np.array([[fx - 2.3 * math.cos(yaw), fy - 2.3 * math.sin(yaw), yaw, 4.6, 1.8]])
    scene = standing(boxes)
    sim.start(["sumo", "-n", net_path, "--no-step-log", "--no-warnings"])
    try:
        seeder = Seeder(sim, net)
        report = seeder.seed(scene)
        assert 0 in report.ids, report.refused
        vid = report.ids[0]
        sim.simulationStep()
        seeder.verify(report)
        status, err = report.status(0)
        # put on its internal lane at its front: on the road, and recorded as far from its pose as it is
        assert sim.vehicle.getLaneID(vid) == inner.id and status == "misplaced", (status, err)
        x, y = sim.vehicle.getPosition(vid)
        assert err == pytest.approx(math.hypot(x - fx, y - fy), abs=1e-3) and 2.0 < err < 3.5
        sim.simulationStep()
        assert vid in sim.vehicle.getIDList()            # SUMO kept it, as the record says
    finally:
        sim.close()
