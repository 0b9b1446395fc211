"""Junction conflicts: generated agents on conflicting internal lanes of one junction (real netconvert
crossing, real libsumo)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.junctions import JunctionConflicts
from sumo_scendiff.sim.seeding import Seeder


def _lane(net, conflicts, a, b):
    """The first internal lane of the connection from edge ``a`` to edge ``b``."""
    for c in net.sumo_net.getEdge(a).getOutgoing()[net.sumo_net.getEdge(b)]:
        return c.getViaLaneID()


def _pose(net, lane_id, along):
    """Box centre and heading ``along`` metres down an internal lane."""
    lane = net.lanes[net.lane_index[lane_id]]
    line = shapely.LineString(lane.shape)
    p, q = line.interpolate(along), line.interpolate(min(along + 0.5, line.length))
    return p.x, p.y, math.atan2(q.y - p.y, q.x - p.x)


def _scene(poses, speeds, score):
    n = len(poses)
    boxes = np.array([[x, y, yaw, 4.6, 1.8] for x, y, yaw in poses])
    traj = np.zeros((n, 5, 3))
    for i, (x, y, yaw) in enumerate(poses):     # straight on at its speed (the lanes are ~straight)
        for k, t in enumerate(range(-2, 3)):
            traj[i, k] = (x + speeds[i] * t * math.cos(yaw), y + speeds[i] * t * math.sin(yaw), yaw)
    mask = np.zeros((n, 5), bool)
    mask[:, :3] = True                          # futures unknown: the route comes from the lane
    return Scene(Window(0.0, 0.0, 0.0), boxes, traj, mask, np.repeat(np.array(speeds, float)[:, None], 5, 1),
                 np.zeros(n), "cross", meta={"score": list(score)})


def _start(cross_net, check_junctions=True):
    import libsumo as sim
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings", "--step-length", "0.5",
               "--lateral-resolution", "0.8"] + (["--collision.check-junctions"] if check_junctions else []))
    return sim


def _calm(sim, steps=20):
    """Step; no collision, nobody braking beyond its decel."""
    for _ in range(steps):
        sim.simulationStep()
        assert sim.simulation.getCollidingVehiclesNumber() == 0
        for v in sim.vehicle.getIDList():
            assert sim.vehicle.getAcceleration(v) >= -sim.vehicle.getDecel(v) - 0.05


@pytest.mark.parametrize("check_junctions", [True, False])
def test_both_in_the_shared_area_one_kept(cross_net, check_junctions):
    """Eastbound straight and northbound straight with their noses in the area both links cross: the
    less probable is not seeded; westbound straight does not cross eastbound and stays. The host runs
    with or without SUMO's junction collision checks: the rule does not depend on them."""
    net = Network.load(cross_net)
    jc = JunctionConflicts(net)
    east, north, west = _lane(net, jc, "wc", "ce"), _lane(net, jc, "sc", "cn"), _lane(net, jc, "ec", "cw")
    assert jc.foes(east, north) and not jc.foes(east, west)
    nose_in = [jc._area(east, north)[0] + 0.5 - 2.3, jc._area(north, east)[0] + 0.5 - 2.3]
    poses = [_pose(net, east, nose_in[0]), _pose(net, north, nose_in[1]), _pose(net, west, 1.0)]
    scene = _scene(poses, [3.0, 3.0, 5.0], [0.9, 0.6, 0.8])
    sim = _start(cross_net, check_junctions)
    try:
        seeder = Seeder(sim, net)
        seeder.red_to_stop_line = False     # the rule alone (the program's first phase has one of them on red)
        report = seeder.seed(scene)
        assert set(report.conflicts) == {1} and "shares" in report.conflicts[1]
        assert set(report.ids) == {0, 2} and not report.refused
        sim.simulationStep()
        assert seeder.verify(report).placed == 2
        _calm(sim)
    finally:
        sim.close()


def test_both_before_the_shared_area_the_later_waits(cross_net):
    """Both a metre into the junction, before the area their links share: both are seeded, the one
    that would reach that area later departs standing and waits; nobody collides or brakes beyond
    decel."""
    net = Network.load(cross_net)
    jc = JunctionConflicts(net)
    east, north = _lane(net, jc, "wc", "ce"), _lane(net, jc, "sc", "cn")
    scene = _scene([_pose(net, east, 1.0), _pose(net, north, 1.0)], [5.0, 5.0], [0.9, 0.6])
    sim = _start(cross_net)
    try:
        seeder = Seeder(sim, net)
        seeder.red_to_stop_line = False     # the rule alone (the program's first phase has one of them on red)
        report = seeder.seed(scene)
        assert not report.conflicts and set(report.ids) == {0, 1}
        b = scene.boxes.astype(float)         # the window is the world frame here
        first = jc.occupancy(east, b[0], 5.0, north)[0] < jc.occupancy(north, b[1], 5.0, east)[0]
        later = 1 if first else 0
        assert set(report.slowed) == {later} and report.slowed[later] == (5.0, 0.0)
        sim.simulationStep()
        assert seeder.verify(report).placed == 2
        _calm(sim)
    finally:
        sim.close()


def test_without_the_rule_the_pair_collides_or_brakes(cross_net):
    """The premise: seeded as generated, the two crossing agents meet, or one escapes that only by
    braking beyond its decel (so the rule is what keeps the previous test calm)."""
    import libsumo as sim
    net = Network.load(cross_net)
    jc = JunctionConflicts(net)
    east, north = _lane(net, jc, "wc", "ce"), _lane(net, jc, "sc", "cn")
    scene = _scene([_pose(net, east, 1.0), _pose(net, north, 1.0)], [5.0, 5.0], [0.9, 0.6])
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings", "--step-length", "0.5",
               "--lateral-resolution", "0.8", "--collision.check-junctions", "--collision.action", "warn"])
    try:
        seeder = Seeder(sim, net)
        seeder.resolve_junctions = False
        seeder.red_to_stop_line = False
        report = seeder.seed(scene)
        assert set(report.ids) == {0, 1}
        collided, brake = 0, 0.0
        for _ in range(20):
            sim.simulationStep()
            collided += sim.simulation.getCollidingVehiclesNumber()
            brake = min([brake] + [sim.vehicle.getAcceleration(v) + sim.vehicle.getDecel(v)
                                   for v in sim.vehicle.getIDList()])
        assert collided > 0 or brake < -0.05
    finally:
        sim.close()


def test_an_agent_past_the_crossing_is_no_conflict(cross_net):
    """Eastbound has already crossed northbound's path (its rear is beyond the overlap of the two
    lanes): both stay. A host vehicle on a foe link is never dropped or held: the agent waits, or is
    not seeded if its nose is in the shared area already."""
    net = Network.load(cross_net)
    jc = JunctionConflicts(net)
    east, north = _lane(net, jc, "wc", "ce"), _lane(net, jc, "sc", "cn")
    length = net.lanes[net.lane_index[east]].length
    done = _pose(net, east, length - 0.2)
    boxes = np.array([[*done, 4.6, 1.8], [*_pose(net, north, 1.0), 4.6, 1.8]])
    keep, hold = jc.resolve([east, north], boxes, [5.0, 5.0], np.array([0.5, 0.9]))
    assert keep.all() and not hold.any()
    early = np.array([[*_pose(net, east, 1.0), 4.6, 1.8]])
    host = (north, boxes[1], 5.0)
    keep, hold = jc.resolve([east], early, [5.0], np.array([0.99]), fixed=[host])
    assert keep.all() and hold.all()                  # before the shared area: it waits
    inside = np.array([[*_pose(net, east, jc._area(east, north)[0] + 0.5 - 2.3), 4.6, 1.8]])
    keep, hold = jc.resolve([east], inside, [5.0], np.array([0.99]), fixed=[host])
    assert not keep.any()                             # in it already: not seeded


def test_links_through_an_internal_junction_meet_on_their_later_lanes(cross2_net):
    """On a two-lane crossing a left turn has two internal lanes (its waiting point between them). An
    agent near the end of the turn's first lane and one just into a foe link share no area on the
    lanes they are on now, but the turn's second lane crosses the other's path: the rule sees that
    (``path_area``) and one of them waits."""
    net = Network.load(cross2_net)
    jc = JunctionConflicts(net)
    turns = [lane for lane, rest in jc.rest.items() if len(rest) > 1 and rest[0] == lane]
    pairs = [(a, b) for a in turns for b in jc.link
             if jc.foes(a, b) and jc._area(a, b) is None and jc.path_area(a, b) is not None
             and jc.entry[b][1] == b and b not in turns]
    assert pairs, "the two-lane crossing has left turns through an internal junction"
    a, b = pairs[0]
    first = shapely.LineString(net.lanes[net.lane_index[a]].shape).length
    assert jc.path_area(a, b)[0] >= first - 1e-6       # on the turn's later lane
    boxes = np.array([[*_pose(net, a, first - 2.5), 4.6, 1.8], [*_pose(net, b, 2.5), 4.6, 1.8]])
    keep, hold = jc.resolve([a, b], boxes, [3.0, 3.0])
    assert keep.all() and hold.sum() == 1


def test_a_vehicle_waiting_on_red_inside_the_junction_goes_to_its_stop_line(cross_net):
    """Eastbound's light is red: a car the model put standing 3 m into the junction on that movement
    is seeded standing at the stop line instead (the scene records the pose, its route keeps the
    movement); a northbound one waiting on red too, whose stop line a host car already stands at,
    queues a minGap behind it. Nobody collides or moves against the light."""
    net = Network.load(cross_net)
    jc = JunctionConflicts(net)
    east, north = _lane(net, jc, "wc", "ce"), _lane(net, jc, "sc", "cn")
    scene = _scene([_pose(net, east, 3.0), _pose(net, north, 3.0)], [0.0, 0.0], [0.9, 0.8])
    sim = _start(cross_net)
    try:
        tls = sim.trafficlight.getIDList()[0]
        sim.trafficlight.setRedYellowGreenState(tls, "r" * len(sim.trafficlight.getRedYellowGreenState(tls)))
        sim.route.add("host", ["sc", "cn"])
        sim.vehicle.add("host", "host", depart="now", departPos=f"{sim.lane.getLength('sc_0') - 3:.1f}",
                        departSpeed="0")
        sim.simulationStep()
        others = np.array([[*sumo_pose(sim, "host"), 5.0, 1.8]])
        seeder = Seeder(sim, net)
        report = seeder.seed(scene, others=(others, np.zeros(1)))
        assert set(report.ids) == {0, 1} and set(report.to_stop_line) == {0, 1} and not report.conflicts
        host_rear = sim.lane.getLength("sc_0") - 3.0 - 5.0
        # the host's fleet is SUMO's default type (5 m): the agents are seeded as it (sim/fleet.py)
        north_nose = scene.boxes[1, 1] + 0.5 * scene.boxes[1, 3]   # northbound: the nose is north of the centre
        assert north_nose == pytest.approx(sim.lane.getShape("sc_0")[0][1] + host_rear - 2.5, abs=0.3)
        end = np.asarray(net.lanes[net.lane_index["wc_0"]].shape[-1])
        nose = scene.boxes[0, :2] + 0.5 * scene.boxes[0, 3] * np.array([math.cos(scene.boxes[0, 2]),
                                                                         math.sin(scene.boxes[0, 2])])
        assert np.hypot(*(nose - end)) < 0.2 and (scene.speed[0] == 0).all()
        vid = report.ids[0]
        assert sim.vehicle.getRoute(vid)[:2] == ("wc", "ce")
        sim.simulationStep()
        assert seeder.verify(report).placed == 2 and sim.vehicle.getLaneID(vid) == "wc_0"
        for _ in range(10):
            sim.simulationStep()
            assert sim.simulation.getCollidingVehiclesNumber() == 0
        assert sim.vehicle.getLaneID(vid) == "wc_0" and sim.vehicle.getSpeed(vid) < 0.1
    finally:
        sim.close()


def sumo_pose(sim, vid):
    from sumo_scendiff.core.geometry import sumo_to_pose
    x, y = sim.vehicle.getPosition(vid)
    return sumo_to_pose(x, y, sim.vehicle.getAngle(vid), sim.vehicle.getLength(vid))


def test_an_agent_seen_only_inside_a_junction_leaves_on_its_movements_lane(cross2_net):
    """Its route is continued from the lane its movement enters (the successors that lane has), not
    from any lane of that edge: a turn its route would take from another lane needs a lane change it
    has no room for."""
    net = Network.load(cross2_net)
    jc = JunctionConflicts(net)
    turn = next(lane for lane, rest in jc.rest.items() if len(rest) > 1 and rest[0] == lane)
    scene = _scene([_pose(net, turn, 1.0)], [4.0], [0.9])
    scene.traj_mask[:] = False
    scene.traj_mask[:, 2] = True              # seen at t = 0 only
    sim = _start(cross2_net)
    try:
        seeder = Seeder(sim, net)
        world = np.asarray(scene.traj[0, :, :2], np.float64)
        edges, _, lane, last_lane = seeder.route_for(scene, 0, world, scene.traj[0, :, 2])
        exit_lane = net.sumo_net.getLane(jc.rest[turn][-1]).getOutgoing()[0].getToLane().getID()
        assert lane.internal and last_lane == exit_lane and edges[-1] == exit_lane.rsplit("_", 1)[0]
    finally:
        sim.close()
