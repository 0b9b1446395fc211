"""sim/session.py: the per-scene pipeline's simulation, as the user sees SUMO speak through it."""
from __future__ import annotations

from sumo_scendiff.sim.session import Session
from sumo_scendiff.sim.sumo import SimConfig

from .conftest import netconvert


def test_sumos_repeated_warnings_while_stepping_are_one_line_each(tmp_path, capfd):
    """With warnings on (-v), a flaw SUMO meets for every vehicle of the demand (trips between two
    roads that do not connect) is one line with its count, not a line per vehicle."""
    net = netconvert('<node id="a" x="0" y="0"/><node id="b" x="200" y="0"/>'
                     '<node id="c" x="0" y="100"/><node id="d" x="200" y="100"/>',
                     '<edge id="ab" from="a" to="b" numLanes="1" speed="13.9"/>'
                     '<edge id="cd" from="c" to="d" numLanes="1" speed="13.9"/>', str(tmp_path / "two.net.xml"))
    routes = tmp_path / "two.rou.xml"
    routes.write_text("<routes>" + "".join(f'<trip id="t{k}" depart="{k}" from="ab" to="cd"/>'
                                           for k in range(10)) + "</routes>")
    cfg = SimConfig(net=net, routes=(str(routes),), extra=("--ignore-route-errors", "true"), begin=0)
    session = Session(cfg, None, None, quiet=False)
    try:
        session.prepare(lambda sim: [sim.simulationStep() for _ in range(30)])
    finally:
        session.close()
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if "No route for vehicle" in ln]
    assert len(lines) == 1 and "times, first: No route for vehicle 't" in lines[0], err
