"""Seeder: generated agents become SUMO vehicles at their generated poses (real libsumo)."""
from __future__ import annotations

import pytest

from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.seeding import Seeder


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


def test_krauss_safe_speed():
    from sumo_scendiff.sim.seeding import krauss_safe_speed
    assert krauss_safe_speed(0.0, 0.0, 4.5, 1.0) == pytest.approx(0.0)
    v = krauss_safe_speed(20.0, 5.0, 4.5, 1.0)    # v tau + v^2 / 2b == g + v_l^2 / 2b
    assert v * 1.0 + v * v / 9.0 == pytest.approx(20.0 + 25.0 / 9.0)
    assert krauss_safe_speed(-3.0, 0.0, 4.5, 1.0) == pytest.approx(0.0)   # overlapping: stand


def test_no_seeded_vehicle_departs_faster_than_it_can_stop(cross_net, cross_scene):
    """A generated queue whose follower moves at 10 m/s a metre behind a standing car departs at the
    Krauss safe speed (seed time, from the scene); one that has a host vehicle standing ahead of it,
    which the scene does not know, is slowed after the seeding step (settle). Neither then brakes
    beyond its decel."""
    import libsumo as sim
    net = Network.load(cross_net)
    scene = cross_scene(net)
    scene.speed[1] = 10.0
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings", "--step-length", "0.5"])
    try:
        sim.route.add("blocker_route", ["sc", "cn"])
        sim.vehicle.add("blocker", "blocker_route", depart="now", departPos="135", departSpeed="0")
        sim.vehicle.setSpeed("blocker", 0.0)
        seeder = Seeder(sim, net)
        report = seeder.seed(scene)
        generated, departure = report.slowed[1]
        assert generated == pytest.approx(10.0) and departure < 1.5 and set(report.slowed) == {1}
        sim.simulationStep()
        report = seeder.settle(seeder.verify(report))
        assert report.placed == 4
        assert report.slowed[2][0] == pytest.approx(8.0) and report.slowed[2][1] < 6.0
        assert sim.vehicle.getSpeed(report.ids[2]) == pytest.approx(report.slowed[2][1], abs=1e-3)
        for _ in range(10):
            sim.simulationStep()
            for vid in report.ids.values():
                assert sim.vehicle.getAcceleration(vid) >= -sim.vehicle.getDecel(vid) - 0.05
        assert sim.simulation.getCollidingVehiclesNumber() == 0
    finally:
        sim.close()


def test_a_queue_behind_a_slowed_vehicle_departs_safe_behind_its_departure_speed(cross_net):
    """A car at 10 m/s three metres behind a standing one departs slowed; the car behind it, at
    13 m/s and 17 m back, departs safe behind the slowed speed, not behind the 10 m/s drawn: no
    one brakes beyond its decel."""
    import math

    import libsumo as sim
    import numpy as np

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import Scene
    net = Network.load(cross_net)
    y = float(next(ln for ln in net.lanes if ln.edge == "wc").shape[0][1])
    xs, speeds = [-40.0, -48.0, -70.0], [0.0, 10.0, 13.0]
    boxes = np.array([[x, y, 0.0, 4.6, 1.8] for x in xs])
    traj = np.zeros((3, 5, 3))
    for i, x in enumerate(xs):
        traj[i, :, 0] = x + speeds[i] * np.arange(-2, 3)
        traj[i, :, 1] = y
    scene = Scene(Window(0.0, 0.0, 0.0), boxes, traj, np.ones((3, 5), bool),
                  np.repeat(np.array(speeds)[:, None], 5, 1), np.zeros(3), "cross")
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings", "--step-length", "0.5"])
    try:
        seeder = Seeder(sim, net)
        report = seeder.seed(scene)
        assert set(report.slowed) == {1, 2}
        assert report.slowed[2][1] < report.slowed[2][0] - 3.0
        sim.simulationStep()
        report = seeder.verify(report)
        assert report.placed == 3
        for _ in range(10):
            for vid in report.ids.values():
                assert sim.vehicle.getAcceleration(vid) >= -sim.vehicle.getDecel(vid) - 0.05, vid
            sim.simulationStep()
        assert sim.simulation.getCollidingVehiclesNumber() == 0
        assert not math.isnan(report.slowed[2][1])
    finally:
        sim.close()


@pytest.mark.parametrize("settle", [True, False])
def test_a_seeded_vehicle_closer_to_its_leader_than_its_min_gap_gets_a_fitting_one(cross_net, cross_scene,
                                                                                    settle):
    """SUMO registers a collision when a gap falls below the follower's minGap, even standing. The
    scene's queue (1 m bumper gap) given a 3 m minGap, as when the scene's leader search misses a
    leader SUMO sees (a sublane neighbour), the leader held standing: settle shrinks the minGap and
    nothing collides; without settle SUMO counts a collision of the two standing cars (after 10 s,
    measured with SUMO 1.28)."""
    import libsumo as sim
    net = Network.load(cross_net)
    scene = cross_scene(net)
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings", "--step-length", "0.5",
               "--lateral-resolution", "0.8", "--collision.check-junctions", "true"])
    try:
        seeder = Seeder(sim, net)
        report = seeder.seed(scene)
        sim.simulationStep()
        report = seeder.verify(report)
        follower = report.ids[1]
        sim.vehicletype.setMinGap(sim.vehicle.getTypeID(follower), 3.0)
        sim.vehicle.setSpeed(report.ids[0], 0.0)
        assert sim.vehicle.getLeader(follower, 50.0)[1] == pytest.approx(1.0 - 3.0, abs=0.3)
        if settle:
            report = seeder.settle(report)
            old, new = report.gap_fitted[1]
            assert old == pytest.approx(3.0) and 0.5 < new < 1.0 and set(report.gap_fitted) == {1}
            assert sim.vehicle.getLeader(follower, 50.0)[1] >= 0.0
        collisions = 0
        for _ in range(30):
            sim.simulationStep()
            collisions += sim.simulation.getCollidingVehiclesNumber()
        assert (collisions == 0) == settle
    finally:
        sim.close()


def test_two_facing_each_other_on_a_lane_both_directions_share_are_not_both_seeded(tmp_path):
    """On a road whose two edges are each other's ``bidi`` (one lane, both directions), of two
    agents facing each other the more probable is seeded and the report names why the other is not;
    one facing a host vehicle already there is not seeded. Neither way do they collide."""
    import libsumo as sim
    import numpy as np

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import Scene

    from .conftest import netconvert
    path = netconvert('<node id="w" x="-200" y="0"/><node id="c" x="0" y="0"/><node id="ww" x="-400" y="0"/>'
                      '<node id="e" x="200" y="0"/>',
                      '<edge id="a" from="w" to="c" numLanes="1" spreadType="center" bidi="-a"/>'
                      '<edge id="-a" from="c" to="w" numLanes="1" spreadType="center" bidi="a"/>'
                      '<edge id="in" from="ww" to="w" numLanes="1"/><edge id="out" from="w" to="ww" numLanes="1"/>'
                      '<edge id="b" from="c" to="e" numLanes="1"/><edge id="-b" from="e" to="c" numLanes="1"/>',
                      str(tmp_path / "bidi.net.xml"))
    net = Network.load(path)
    y = float(net.lanes[net.lane_index["a_0"]].shape[0][1])
    w = Window(-100.0, 0.0, 0.0)
    boxes = np.array([[-20.0, y, 0.0, 4.5, 1.8], [40.0, y, np.pi, 4.5, 1.8]])   # scene frame: east on a, west on -a
    traj = np.repeat(boxes[:, None, :3], 5, 1)
    for score, dropped in (([0.9, 0.95], 0), ([0.97, 0.85], 1)):
        scene = Scene(w, boxes, traj, np.ones((2, 5), bool), np.zeros((2, 5)),
                      np.zeros(2), "t", meta={"score": score})
        sim.start(["sumo", "-n", path, "--no-step-log", "--no-warnings", "--collision.check-junctions", "true"])
        try:
            report = Seeder(sim, net).seed(scene)
            assert set(report.ids) == {1 - dropped} and "both directions share" in report.conflicts[dropped]
            for _ in range(10):
                sim.simulationStep()
                assert not sim.simulation.getCollisions()
        finally:
            sim.close()
    keep = np.ones(1, bool)
    seeder = Seeder.__new__(Seeder)          # the rule alone, on world boxes
    seeder.net = net
    east, host = np.array([[-120.0, y, 0.0, 4.5, 1.8]]), np.array([[-60.0, y, np.pi, 4.5, 1.8]])
    assert seeder.facing_on_shared_lanes(east, host, keep, None) == {0: "a_0"}
    assert seeder.facing_on_shared_lanes(east, np.zeros((0, 5)), keep, None) == {}


def test_an_agent_where_a_vehicle_was_moved_before_is_not_seeded(cross_net, cross_scene):
    """A window is drawn around the vehicles already there, but the seeder may have moved one of
    them since (pulled back from over a stop line): an agent whose box overlaps it is not seeded,
    and the report says why; the others are."""
    import libsumo as sim
    import numpy as np
    net = Network.load(cross_net)
    scene = cross_scene(net)
    moved = scene.boxes[2:3, :5].copy()        # a vehicle seeded before, now where agent 2 stands
    moved[0, 1] -= 1.0
    assert Seeder.on_others(scene, moved) == {2: "its box overlaps a vehicle seeded before"}
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings"])
    try:
        report = Seeder(sim, net).seed(scene, others=(moved, np.zeros(1)))
    finally:
        sim.close()
    assert 2 not in report.ids and "overlaps a vehicle seeded before" in report.dropped[2]
    assert report.status(2) == ("dropped", report.dropped[2])
    assert {0, 1} <= set(report.ids)


def test_a_vehicle_sumo_does_not_have_after_the_seeding_step_is_refused(cross_net, cross_scene):
    """Every agent is exactly one of placed, misplaced, refused, dropped: one SUMO does not have after
    the seeding step (here the host took it out before the step) is refused with the reason, no
    vehicle id left in the record (it was counted as a misplaced vehicle), and the counts add up."""
    import libsumo as sim
    net = Network.load(cross_net)
    scene = cross_scene(net)
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings"])
    try:
        seeder = Seeder(sim, net)
        report = seeder.seed(scene)
        sim.vehicle.remove(report.ids[0])
        sim.simulationStep()
        seeder.verify(report)
        left = set(sim.vehicle.getIDList())
    finally:
        sim.close()
    status, why = report.status(0)
    assert status == "refused" and "not in the simulation after the seeding step" in why
    assert 0 not in report.ids and 0 not in report.misplaced and left == set(report.ids.values())
    assert report.status(4)[0] == "refused" and report.placed == 3
    assert report.counts(len(scene)) == {"generated": 5, "placed": 3, "misplaced": 0, "refused": 2, "existing": 0, "dropped": 0}
