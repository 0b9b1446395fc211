"""Routes of seeded agents: the generated part, then SUMO's fastest route to a destination (real libsumo)."""
from __future__ import annotations

from itertools import pairwise

import numpy as np

from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.routes import RouteChooser


def _turns_back(snet, edges) -> bool:
    es = [snet.getEdge(e) for e in edges]
    return any(b.getToNode() is a.getFromNode() and b.getFromNode() is a.getToNode() for a, b in pairwise(es))


def test_without_demand_a_route_ends_at_the_fringe(cross_net):
    """An empty host: destinations are the edges that leave the crossing (cw, ce, cs, cn); the route
    from wc takes one of them straight away (the fastest path), never back to cw's reverse, and the
    same seed draws the same one."""
    import libsumo as sim
    net = Network.load(cross_net)
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings"])
    try:
        rc = RouteChooser(sim, net)
        assert rc.fringe == ["ce", "cn", "cs", "cw"]
        rc.refresh()
        assert rc.targets == rc.fringe
        routes = [rc.complete(["wc"], "wc_0", "DEFAULT_VEHTYPE", np.random.default_rng(s)) for s in range(12)]
        for r in routes:
            assert r[0] == "wc" and len(r) == 2 and r[1] in ("ce", "cn", "cs")   # cw would be a U-turn
        assert len({r[1] for r in routes}) > 1                                  # drawn, not fixed
        again = [rc.complete(["wc"], "wc_0", "DEFAULT_VEHTYPE", np.random.default_rng(s)) for s in range(12)]
        assert again == routes
    finally:
        sim.close()


def test_with_demand_a_route_goes_where_the_host_traffic_goes(grid):
    """A host whose vehicles all drive to one edge: every seeded route ends there, by a shortest path
    (as many edges as sumolib's shortest path on this uniform grid), without a loop or a U-turn; the
    seeder's own vehicles do not count as demand."""
    import libsumo as sim
    snet = grid.sumo_net
    sim.start(["sumo", "-n", grid.path, "--no-step-log", "--no-warnings"])
    try:
        edges = sorted(e.getID() for e in snet.getEdges(withInternal=False))
        dest = "A0B0" if "A0B0" in edges else edges[0]
        far = next(e for e in reversed(edges) if len(sim.simulation.findRoute(e, dest).edges) >= 4)
        sim.route.add("host_route", list(sim.simulation.findRoute(far, dest).edges))
        for k in range(3):
            sim.vehicle.add(f"host{k}", "host_route", depart="now")
        sim.route.add("own_route", [far])
        sim.vehicle.add("sd0", "own_route", depart="now")         # a seeded vehicle: not demand
        sim.simulationStep()
        rc = RouteChooser(sim, grid, exclude_prefix="sd")
        rc.refresh()
        assert rc.targets == [dest]
        starts = [e for e in edges if e != dest and snet.getEdge(e).allows("passenger")]
        checked = 0
        for start in starts:
            r = rc.complete([start], None, "DEFAULT_VEHTYPE", np.random.default_rng(0))
            if len(r) == 1:      # dest unreachable without turning back where it came from
                continue
            checked += 1
            assert r[0] == start and r[-1] == dest
            assert len(set(r)) == len(r) and not _turns_back(snet, r)
            shortest, _ = snet.getShortestPath(snet.getEdge(start), snet.getEdge(dest))
            assert len(r) <= len(shortest) + 2        # a U-turn-free detour is at most a block longer
        assert checked >= len(starts) // 2
    finally:
        sim.close()


def test_the_first_turn_is_one_the_lane_makes(tmp_path):
    """A two-lane arm whose right lane turns right or goes straight and whose left lane turns left:
    an agent in the right lane is never routed left (a turn its lane does not make, which it could
    only reach by changing lanes at the stop line); one in the left lane goes left."""
    import libsumo as sim

    from .conftest import netconvert
    nodes = ('<node id="c" x="0" y="0" type="priority"/><node id="w" x="-200" y="0"/>'
             '<node id="e" x="200" y="0"/><node id="s" x="0" y="-200"/><node id="n" x="0" y="200"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="{2 if a + b == "wc" else 1}" '
                    f'speed="13.89"/>' for a, b in (("w", "c"), ("c", "w"), ("e", "c"), ("c", "e"),
                                                   ("s", "c"), ("c", "s"), ("n", "c"), ("c", "n")))
    path = netconvert(nodes, edges, str(tmp_path / "two.net.xml"))
    net = Network.load(path)
    assert {c.getTo().getID() for c in net.sumo_net.getLane("wc_0").getOutgoing()} == {"cs", "ce"}
    sim.start(["sumo", "-n", path, "--no-step-log", "--no-warnings"])
    try:
        rc = RouteChooser(sim, net)
        rc.refresh()
        right = [rc.complete(["wc"], "wc_0", "DEFAULT_VEHTYPE", np.random.default_rng(s)) for s in range(16)]
        assert all(r[1] in ("cs", "ce") for r in right) and len({r[1] for r in right}) == 2
        left = [rc.complete(["wc"], "wc_1", "DEFAULT_VEHTYPE", np.random.default_rng(s)) for s in range(4)]
        assert all(r == ["wc", "cn"] for r in left)
        # without a known lane (an agent seen only inside the junction) any turn of the edge is fine
        free = [rc.complete(["wc"], None, "DEFAULT_VEHTYPE", np.random.default_rng(s)) for s in range(16)]
        assert {r[1] for r in free} == {"cs", "ce", "cn"}
        # from ce (a fringe edge, nothing beyond): the route is the generated part alone
        assert rc.complete(["wc", "ce"], "ce_0", "DEFAULT_VEHTYPE", np.random.default_rng(0)) == ["wc", "ce"]
    finally:
        sim.close()


def test_a_demand_vehicle_keeps_its_own_route_that_turns_back(tmp_path):
    """A demand route may turn back at a dead end and pass an edge twice (duarouter's and OSM
    scenarios' routes do): the vehicle an agent stands for drives it as given, not a destination
    drawn for it; where its generated part left that route, SUMO's router takes it to its own
    destination, turning back where that is the way."""
    import libsumo as sim

    from .conftest import crossing
    cross_net = crossing(str(tmp_path / "turn.net.xml"), 1, turnarounds=True)
    net = Network.load(cross_net)
    snet = net.sumo_net
    assert "ec" in {c.getTo().getID() for c in snet.getLane("ce_0").getOutgoing()}   # netconvert's turnaround
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings"])
    try:
        rc = RouteChooser(sim, net)
        rc.refresh()
        wanted = ["wc", "ce", "ec", "cn"]                      # to e's dead end, back, then north
        assert rc.along(["wc"], "wc_0", wanted, "DEFAULT_VEHTYPE") == (wanted, "followed")
        looped = ["wc", "ce", "ec", "cw", "wc", "cs"]         # wc twice
        assert rc.along(["wc"], "wc_0", looped, "DEFAULT_VEHTYPE") == (looped, "followed")
        # generated into ce, off a route to cs: back through e's turnaround to its destination
        route, how = rc.along(["wc", "ce"], "ce_0", ["wc", "cn", "nc", "cs"], "DEFAULT_VEHTYPE")
        assert (route, how) == (["wc", "ce", "ec", "cs"], "rerouted")
        # a route we choose ourselves still never turns back
        assert not _turns_back(snet, rc.complete(["wc"], "wc_0", "DEFAULT_VEHTYPE", np.random.default_rng(0)))
    finally:
        sim.close()
