"""Saved states (sim/state.py): what a state holds beyond the vehicles on the road."""
from __future__ import annotations


def test_the_vehicles_waiting_to_enter_are_counted_from_the_state(tmp_path, grid):
    """A flow denser than its lane takes: SUMO queues the rest. The state keeps the queue, a SUMO
    started from it shows none until its next step; the count from the file is SUMO's own queue."""
    import libsumo as sim

    from sumo_scendiff.sim.state import save_state, waiting_in_state
    routes = tmp_path / "r.rou.xml"
    routes.write_text('<routes><vType id="car" length="4.5"/>'   # a type: SUMO writes it before depart
                      '<flow id="f" type="car" begin="0" end="200" period="0.2" from="A0B0" to="B0C0"/>'
                      '<flow id="g" begin="0" end="200" period="0.4" from="A0B0" to="B0C0"/>'
                      '<vehicle id="later" depart="100"><route edges="A0B0 B0C0"/></vehicle></routes>')
    state = str(tmp_path / "state.xml.gz")
    sim.start(["sumo", "-n", grid.path, "-r", str(routes), "--no-step-log", "--no-warnings"])
    try:
        for _ in range(20):
            sim.simulationStep()
        queued = len(sim.simulation.getPendingVehicles())
        save_state(sim, state)
        counted = waiting_in_state(state, sim.vehicle.getIDList(), sim.simulation.getTime())
    finally:
        sim.close()
    assert queued > 50 and counted == queued
    sim.start(["sumo", "-n", grid.path, "-r", str(routes), "--load-state", state, "--no-step-log", "--no-warnings"])
    try:
        assert len(sim.simulation.getPendingVehicles()) == 0   # why the file is read: not yet queued again
        sim.simulationStep()
        assert len(sim.simulation.getPendingVehicles()) >= queued - 3   # the queue again (a few got in, new ones due)
    finally:
        sim.close()
