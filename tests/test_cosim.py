"""Co-simulation API on a simulation the caller runs (real libsumo, shipped model)."""
from __future__ import annotations

import numpy as np
import pytest
import shapely

from sumo_scendiff.core.geometry import Window, box_corners
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.cosim import CoSimulation, token_assignment
from sumo_scendiff.sim.sumo import SimConfig, start


def _demand(tmp_path) -> str:
    path = tmp_path / "d.rou.xml"
    path.write_text("<routes>" + "".join(
        f'<vehicle id="e{k}" depart="{3 * k}"><route edges="wc ce"/></vehicle>'
        f'<vehicle id="s{k}" depart="{3 * k + 1}"><route edges="sc cn"/></vehicle>' for k in range(8))
        + "</routes>")
    return str(path)


def test_seed_around_keeps_existing_vehicles_and_reseeds_ahead(cross_net, tmp_path):
    net = Network.load(cross_net)
    gen = ScenarioGenerator.load(config=GenerationConfig(steps=8, threshold=0.5))
    sim = start(SimConfig(net=cross_net, routes=(_demand(tmp_path),)))
    try:
        while "e3" not in sim.vehicle.getIDList():
            sim.simulationStep()
        cosim = CoSimulation(sim, net, gen, seed=1)
        w = cosim.ego_window("e3")
        assert abs(w.yaw) < 0.05
        before = set(sim.vehicle.getIDList())
        ex = cosim.existing(w)
        assert "e3" in ex.token_ids() and len(ex.tokens()) == int(ex.inside.sum())
        seeding = cosim.seed_around("e3", p_mask=0.8)
        assert not set(seeding.agent_ids) & before          # nobody re-added
        assert seeding.token_source[: len(ex.token_ids())] == ex.token_ids()
        # no seeded agent on top of a vehicle that was already there
        occupied = shapely.union_all(shapely.polygons(box_corners(*ex.boxes.T)))
        mine = shapely.polygons(box_corners(*seeding.scene.boxes.T.astype(np.float64)))
        assert not shapely.intersects(mine, occupied).any()
        sim.simulationStep()
        cosim.verify(seeding)
        assert before <= set(sim.vehicle.getIDList()) | set(sim.simulation.getArrivedIDList())
        assert cosim.reseed_ahead("e3", every_m=30.0) is None    # has not moved 30 m yet
        x0 = np.asarray(sim.vehicle.getPosition("e3"))
        while np.hypot(*(np.asarray(sim.vehicle.getPosition("e3")) - x0)) < 30.0:
            sim.simulationStep()
        again = cosim.reseed_ahead("e3", every_m=30.0, ahead_m=60.0)
        assert again is not None
        ex_x = sim.vehicle.getPosition("e3")[0]
        assert again.scene.window.cx > ex_x + 50.0             # the window ahead of the ego
    finally:
        sim.close()


def test_token_assignment_matches_by_position_and_heading():
    boxes = np.array([[10.0, 0.0, 0.0, 4.5, 1.8], [-20.0, 5.0, np.pi / 2, 4.5, 1.8], [0, 30, 0, 4, 2]])
    scene = Scene(Window(0, 0), boxes, np.zeros((3, 5, 3)), np.ones((3, 5), bool), np.zeros((3, 5)), np.zeros(3))
    tokens = [{"x": -19.0, "y": 5.5, "heading": np.pi / 2}, {"speed": 3.0}, {"x": 10.5, "y": 0.0},
              {"x": 0.0, "y": 30.0, "heading": np.pi}]         # last: right place, wrong heading
    assert token_assignment(scene, tokens) == [2, 0, None]


def test_place_drops_agents_on_existing_vehicles_and_their_tokens(cross_net, cross_scene):
    from sumo_scendiff.sim.cosim import Existing
    net = Network.load(cross_net)
    scene = cross_scene(net)
    # a host vehicle exactly where agent 0 stands, another one 1 m beside agent 2 (touching it)
    ex = Existing(["host0", "host1"], np.array([scene.boxes[0], scene.boxes[2] + [1.0, 0, 0, 0, 0]], np.float64),
                  np.zeros(2), np.array([True, True]))
    sim = start(SimConfig(net=cross_net))
    try:
        cosim = CoSimulation(sim, net, generator=None)
        seeding = cosim.place(scene, ex.tokens(), ex.token_ids(), ex)
        # both the model's copies of the host's vehicles (matched to their tokens): kept, the copies not added
        assert (seeding.copies, seeding.dropped) == (2, 0) and len(seeding.scene) == 3
        np.testing.assert_allclose(seeding.scene.boxes, scene.boxes[[1, 3, 4]])
        assert seeding.token_of == [None, None, None]
    finally:
        sim.close()


def test_replay_future_holds_agents_on_their_generated_future(cross_net):
    """An agent braking from 8 m/s to a stop in 2 s (the paper's "stopping" token): after the replay
    it stands at its generated +2 s pose, not where SUMO's car-following would have taken it."""
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import Scene
    net = Network.load(cross_net)
    east = next(ln for ln in net.lanes if ln.edge == "wc")
    y = float(east.shape[0][1])
    xs = np.array([-96.0, -88.0, -80.0, -76.0, -74.0])     # 8 m/s, then braking to a stop at -74
    traj = np.stack([xs, np.full(5, y), np.zeros(5)], -1)[None]
    speed = np.array([[8.0, 8.0, 6.0, 3.0, 1.0]])
    scene = Scene(Window(0, 0), [[-80.0, y, 0.0, 4.6, 1.8]], traj, np.ones((1, 5), bool), speed, [0])
    sim = start(SimConfig(net=cross_net))
    try:
        cosim = CoSimulation(sim, net, generator=None)
        ex = cosim.existing(scene.window)
        seeding = cosim.place(scene, [], [], ex)
        sim.simulationStep()
        cosim.verify(seeding)
        assert seeding.report.placed == 1
        vid = seeding.agent_ids[0]
        cosim.replay_future(seeding, 2.0)
        x, _ = sim.vehicle.getPosition(vid)                 # front bumper
        assert x - 2.3 == pytest.approx(-74.0, abs=0.3)
        assert sim.vehicle.getSpeed(vid) < 2.0
    finally:
        sim.close()


def test_an_agent_the_host_vehicle_behind_cannot_stop_for_is_dropped(cross_net, cross_scene):
    """A host vehicle (the caller's ego, say) at 14 m/s 12 m behind a generated car standing in its
    lane would brake beyond its decel: that car is dropped with the reason; at 2 m/s it is seeded."""
    import libsumo

    from sumo_scendiff.sim.cosim import Existing
    net = Network.load(cross_net)
    scene = cross_scene(net)
    behind = scene.boxes[1] - [12.0, 0, 0, 0, 0]          # agent 1 stands at the queue's tail
    sim = start(SimConfig(net=cross_net))
    try:
        sim.route.add("r", ["wc", "ce"])
        sim.vehicle.add("ego", "r", departSpeed="0")
        sim.simulationStep()
        cosim = CoSimulation(sim, net, generator=None)
        for speed, dropped in ((14.0, True), (2.0, False)):
            ex = Existing(["ego"], np.array([behind], np.float64), np.array([speed]), np.array([False]))
            seeding = cosim.place(scene, [], [], ex)
            reasons = [w for w in seeding.before_reason if "cannot stop behind it" in w]
            assert bool(reasons) == dropped, (speed, seeding.before_reason)
            for vid in list(seeding.agent_ids):
                libsumo.vehicle.remove(vid)
            sim.simulationStep()
    finally:
        sim.close()


def test_seeded_vehicles_that_leave_leave_no_vtype_or_route_behind(cross_net):
    """A co-simulation seeding window after window, each seeding's vehicles driving out of the
    network before the next: no vType or route SUMO holds once they have left is one of a vehicle
    (SUMO's own vTypes and the seeder's one per vehicle class remain, and one route per edge for a
    route of one edge), however many vehicles were seeded; while a seeded vehicle drives, its vType
    is its own (``{type}@{id}``, SUMO's vehicle-specific type) with the box it was seeded with."""
    from sumo_scendiff.core.scene import VEHICLE_CLASSES
    net = Network.load(cross_net)
    gen = ScenarioGenerator.load(config=GenerationConfig(steps=8, threshold=0.5))
    sim = start(SimConfig(net=cross_net))
    try:
        allowed = set(sim.vehicletype.getIDList()) | {f"sd_{c}" for c in VEHICLE_CLASSES}
        edges = {e.getID() for e in net.sumo_net.getEdges(withInternal=False)}
        cosim = CoSimulation(sim, net, gen, seed=3)
        seeded = 0
        for _ in range(3):
            seeding = cosim.seed_window(Window(0.0, 0.0, 0.0), vehicles=8)
            sim.simulationStep()
            cosim.verify(seeding, warn=False)
            present = [(i, v) for i, v in seeding.report.ids.items() if v in sim.vehicle.getIDList()]
            for i, vid in present:
                assert sim.vehicle.getTypeID(vid).endswith(f"@{vid}")
                assert sim.vehicle.getLength(vid) == pytest.approx(float(seeding.scene.boxes[i, 3]), abs=1e-3)
            seeded += len(present)
            while sim.vehicle.getIDCount():
                sim.simulationStep()
            assert set(sim.vehicletype.getIDList()) <= allowed
            assert {r.split(":", 1)[-1] for r in sim.route.getIDList()} <= edges    # no vehicle's route
        assert seeded >= 12
    finally:
        sim.close()
