"""The demand estimate's clock (fill/travel.py): the lights' programs and load, the junctions'
internal lanes, vTypes and departures, on the project's generated networks."""
from __future__ import annotations

import os

import numpy as np
import pytest

NETS = os.path.join(os.path.dirname(__file__), "..", "networks")
NET4 = os.path.join(NETS, "grid4x4_2lane_tls.net.xml")


def test_green_shares_and_an_additional_program(tmp_path):
    """A light's program gives each link its green share (amber half); an additional file's
    program replaces the network's, as in SUMO."""
    from sumo_scendiff.fill.programs import green_shares, signal_programs
    a = tmp_path / "a.add.xml"
    a.write_text('<additional><tlLogic id="J" type="static" programID="1" offset="0">'
                 '<phase duration="30" state="Gr"/><phase duration="4" state="yr"/>'
                 '<phase duration="26" state="rG"/></tlLogic></additional>')
    cycle, green = green_shares(signal_programs([str(a)]))["J"]
    assert cycle == 60 and green == pytest.approx([32 / 60, 26 / 60])
    b = tmp_path / "b.add.xml"
    b.write_text(a.read_text().replace('duration="26"', 'duration="56"'))
    assert green_shares(signal_programs([str(a), str(b)]))["J"][0] == 90


def _signalised_pairs(net):
    """(edge, next) pairs of the network whose connections a traffic light controls, straight and turning."""
    straight, turn = [], []
    for e in net.sumo_net.getEdges():
        for nxt, conns in e.getOutgoing().items():
            if conns and conns[0].getTLSID():
                (straight if conns[0].getDirection() == "s" else turn).append((e.getID(), nxt.getID()))
    return straight, turn


def test_a_lights_wait_is_webster_and_grows_with_its_load():
    """Unloaded, the wait at a light is Webster's uniform delay C (1 - λ)² / 2; the demand's flow
    through the link lengthens it (1 / (1 - λx), and the random arrivals' x² / (2q (1 - x)) less
    Webster's correction), never without bound."""
    from sumo_scendiff.fill.travel import SATURATION_FLOW, X_MAX, TravelTimes, webster
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    (e, nxt), *_ = _signalised_pairs(net)[0]
    free = TravelTimes(net)
    link = free.link_of(e, nxt)
    assert 0 < link.green < 1 and link.cycle > 0
    wait, _ = free.link(e, nxt)
    assert wait == pytest.approx(link.cycle * (1 - link.green) ** 2 / 2)
    q = 0.5 * SATURATION_FLOW * link.lanes * link.green
    half = TravelTimes(net, flows={(e, nxt): q})
    over = TravelTimes(net, flows={(e, nxt): 10 * SATURATION_FLOW * link.lanes})
    w_half, w_over = half.link(e, nxt)[0], over.link(e, nxt)[0]
    assert wait < w_half < w_over < 1e4
    uniform = wait / (1 - 0.5 * link.green)
    random = 0.25 / (2 * q * 0.5)
    correction = 0.65 * (link.cycle / q ** 2) ** (1 / 3) * 0.5 ** (2 + 5 * link.green)
    assert w_half == pytest.approx(webster(link.cycle, link.green, 0.5, q))
    assert w_half == pytest.approx(max(uniform + random - correction, uniform))
    assert w_over == pytest.approx(webster(link.cycle, link.green, X_MAX, 10 * SATURATION_FLOW * link.lanes))
    # Webster's correction never takes the wait below the uniform delay
    assert webster(90.0, 0.45, 0.3, 0.4) >= 90.0 * 0.55 ** 2 / (2 * (1 - 0.45 * 0.3))


def test_a_turn_takes_longer_across_the_junction_than_going_straight():
    """The internal lanes of a turn are slower (netconvert lowers their speed for the radius), and
    slowing for them costs time; a route's end has no junction."""
    from sumo_scendiff.fill.travel import TravelTimes
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    times = TravelTimes(net)
    straight, turn = _signalised_pairs(net)
    s = min(times.link(e, n)[1] / max(times.link_of(e, n).via_m, 1e-3) for e, n in straight)
    t = max(times.link(e, n)[1] / max(times.link_of(e, n).via_m, 1e-3) for e, n in turn)
    assert t > s                    # s per metre across the junction
    assert times.link(straight[0][0], None) == (0.0, 0.0)


def test_vtype_drivers(tmp_path):
    """A vType's speedFactor (a distribution: its mean), maxSpeed, accel and decel; a class's
    defaults where not given; a distribution is its first member."""
    from sumo_scendiff.fill.travel import DEFAULT_DRIVER, vtype_drivers
    f = tmp_path / "t.add.xml"
    f.write_text('<additional><vType id="slow" speedFactor="normc(0.8,0.1,0.2,2)" accel="1.5"/>'
                 '<vType id="bus" vClass="bus"/><vTypeDistribution id="mix" vTypes="slow bus"/>'
                 '<vType id="calm" sigma="0"/><vType id="idm" carFollowModel="IDM"/>'
                 '</additional>')
    d = vtype_drivers([str(f)])
    # Krauss' dawdling takes sigma x accel x U(0, 1) off each step's gain: half of it on average
    assert d["slow"].sigma == 0.5 and d["slow"].pickup == pytest.approx(1.5 * 0.75)
    assert d["calm"].pickup == d["calm"].accel and d["idm"].sigma == 0.0
    assert d["calm"].slowing(10.0, 0.0) < DEFAULT_DRIVER.slowing(10.0, 0.0)     # the same accel, no dawdling
    assert d["slow"].speed_factor == pytest.approx(0.8) and d["slow"].accel == 1.5
    assert d["slow"].decel == DEFAULT_DRIVER.decel
    assert d["bus"].max_speed < DEFAULT_DRIVER.max_speed and d["bus"].accel < DEFAULT_DRIVER.accel
    assert d["mix"] == d["slow"]
    assert d["slow"].cruise(13.89) < DEFAULT_DRIVER.cruise(13.89)


def test_depart_pos_and_speed_in_the_estimate(tmp_path):
    """A vehicle entering halfway along its edge (departPos) is through it sooner than one entering
    at its start; one entering at speed (departSpeed="max") sooner than one from standing
    (departSpeed="0"; without one, SUMO's default decides: test_fill_demand.py)."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    e = max(net.sumo_net.getEdges(), key=lambda x: x.getLength())
    routes = tmp_path / "d.rou.xml"

    def remaining(attrs: str) -> float:
        routes.write_text(f'<routes><vehicle id="a" depart="0" {attrs}><route edges="{e.getID()}"/></vehicle></routes>')
        [v] = DemandEstimate.at(net, [str(routes)], begin=1.0).en_route
        return v.travel - v.since, v.offset
    base, off = remaining('departSpeed="0"')
    half, off_half = remaining(f'departPos="{e.getLength() / 2:.2f}" departSpeed="0"')
    moving, _ = remaining('departSpeed="max"')
    assert off == 0 and off_half == pytest.approx(e.getLength() / 2, abs=0.01)
    assert half < base and moving < base


def _priority_crossing(tmp_path, kind: str = "priority") -> str:
    """An unsignalised crossing: the west-east road has the right of way over the south-north one."""
    from .conftest import netconvert
    nodes = (f'<node id="c" x="0" y="0" type="{kind}"/><node id="w" x="-200" y="0"/><node id="e" x="200" y="0"/>'
             '<node id="s" x="0" y="-200"/><node id="n" x="0" y="200"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="1" speed="13.89" priority="{p}"/>'
                    for a, b, p in (("w", "c", 2), ("c", "w", 2), ("e", "c", 2), ("c", "e", 2),
                                    ("s", "c", 1), ("c", "s", 1), ("n", "c", 1), ("c", "n", 1)))
    return netconvert(nodes, edges, str(tmp_path / f"{kind}.net.xml"))


def test_a_minor_link_waits_for_a_gap_in_the_flows_it_yields_to(tmp_path):
    """Crossing the main road from the side road waits Adams' delay for a gap of YIELD_GAP s in the
    main road's flow (none without it); the main road never waits; at an all-way stop every
    vehicle stops."""
    import numpy as np

    from sumo_scendiff.fill.travel import YIELD_GAP, TravelTimes
    from sumo_scendiff.map.network import Network
    net = Network.load(_priority_crossing(tmp_path))
    minor = TravelTimes(net).link_of("sc", "cn")
    assert {(f, t) for f, t, *_ in minor.foes} >= {("wc", "ce"), ("ec", "cw")} and not minor.stop
    assert TravelTimes(net).link_of("wc", "ce").foes == ()
    assert TravelTimes(net).link("sc", "cn")[0] == 0.0          # nobody on the main road
    q = 0.2
    times = TravelTimes(net, flows={("wc", "ce"): q, ("sc", "cn"): 1e-9})
    wait, _ = times.link("sc", "cn")
    assert wait == pytest.approx((np.exp(q * YIELD_GAP) - q * YIELD_GAP - 1) / q, rel=1e-6)
    assert times.link("wc", "ce")[0] == 0.0
    busier = TravelTimes(net, flows={("wc", "ce"): q, ("ec", "cw"): q, ("sc", "cn"): 0.05})
    assert busier.link("sc", "cn")[0] > wait
    stop = Network.load(_priority_crossing(tmp_path, "allway_stop"))
    link = TravelTimes(stop).link_of("sc", "cn")
    assert link.stop and TravelTimes(stop).yielding(link, "sc", "cn") == (0.0, 1.0)


def test_a_left_turn_at_a_light_yields_only_to_the_foes_green_with_it(cross_net):
    """At a light the net.xml states are those of the light switched off; the program says who
    yields: the left turn, a yielding green g, gives way to the opposing straight stream green at
    the same time, never to the cross street (red then); the straight link yields to nobody."""
    from sumo_scendiff.fill.programs import minor_green, signal_programs
    from sumo_scendiff.fill.travel import TravelTimes
    from sumo_scendiff.map.network import Network
    net = Network.load(cross_net)
    times = TravelTimes(net)
    left = times.link_of("wc", "cn")
    assert ("ec", "cw") in {(f, t) for f, t, *_ in left.foes}
    assert all(f in ("wc", "ec") for f, *_ in left.foes)          # nothing from the cross street
    assert all(w == 1.0 for *_, w in left.foes)                    # all its green is a yielding g
    assert times.link_of("wc", "ce").foes == ()
    busy = TravelTimes(net, flows={("ec", "cw"): 0.2})
    assert busy.link("wc", "cn")[0] > times.link("wc", "cn")[0]
    assert busy.link("wc", "ce")[0] == times.link("wc", "ce")[0]
    [(_, program)] = signal_programs([cross_net]).items()
    phases = program.phases
    k = phases[0][1].index("g")
    assert minor_green(phases, k, 0) == 1.0 and minor_green(phases, 0, k) == 0.0


def test_a_fixed_program_is_sumos_clock(cross_net):
    """A static program's phases run from simulation time 0 shifted by its offset, whatever the
    begin: Program.next_green(k, t) is t exactly when SUMO shows link k green over the step before
    t (SUMO switches a phase after the step that reaches its end)."""
    import libsumo

    from sumo_scendiff.fill.programs import Program, signal_programs
    [(tls, program)] = signal_programs([cross_net]).items()
    assert program.fixed and program.cycle == 90
    libsumo.start(["sumo", "-n", cross_net, "--begin", "1234", "--no-step-log", "--no-warnings"])
    try:
        for _ in range(200):
            t = libsumo.simulation.getTime()
            state = libsumo.trafficlight.getRedYellowGreenState(tls)
            for k, c in enumerate(state):
                assert (program.next_green([k], t - 0.5) == t - 0.5) == (c in "Ggs"), (t, k, state)
            libsumo.simulationStep()
    finally:
        libsumo.close()
    shifted = Program(((30.0, "Gr"), (5.0, "yr"), (30.0, "rG"), (5.0, "ry")), offset=10.0)
    assert shifted.next_green([0], 10.0) == 10.0 and shifted.next_green([0], 45.0) == 80.0
    assert shifted.next_green([1], 10.0) == 45.0 and shifted.next_green([1], 76.0) == 115.0
    assert Program(((30.0, "Gr"),)).next_green([1], 0.0) == float("inf")


def test_a_queue_at_a_fixed_light_waits_for_green_and_leaves_one_per_headway(tmp_path, cross_net):
    """Vehicles reaching a red light wait at its stop line until its green, then go one per
    saturation headway, first come first served: at each instant the estimate has as many still
    waiting as have not had their turn."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.travel import SATURATION_FLOW, TravelTimes
    from sumo_scendiff.map.network import Network
    net = Network.load(cross_net)
    times = TravelTimes(net)
    link = times.link_of("wc", "ce")
    program = times.light(link)
    routes = tmp_path / "q.rou.xml"
    # when the first would reach the line, and the green after the last has reached it
    reach = times.edge("wc")[0]
    red = next(t for t in range(90) if program.next_green(link.indices, t + reach) > t + reach + 20)
    green = program.next_green(link.indices, red + 5 + reach)
    headway = 1.0 / (SATURATION_FLOW * link.lanes)
    routes.write_text("<routes>" + "".join(
        f'<vehicle id="v{i}" depart="{red + i}" departSpeed="max"><route edges="wc ce"/></vehicle>'
        for i in range(6)) + "</routes>")
    for gone in range(4):
        est = DemandEstimate.at(net, [str(routes)], begin=green + gone * headway + 0.5 * headway)
        waiting = [v for v in est.en_route if v.edges[0] == "wc"]
        assert len(waiting) == 6 - gone - 1 and all(v.waiting for v in waiting)
        assert sorted(v.id for v in waiting) == [f"v{i}" for i in range(gone + 1, 6)]
    assert est.on_edge["ce"] == 4


def test_green_end_is_the_end_of_the_green_a_link_shows():
    from sumo_scendiff.fill.programs import Program
    p = Program(((30.0, "Gr"), (5.0, "yr"), (30.0, "rG"), (5.0, "ry")), offset=10.0)
    assert p.green_end([0], 10.0) == 40.0 and p.green_end([0], 39.0) == 40.0
    assert p.green_end([0], 40.0) is None and p.green_end([1], 40.0) is None
    assert p.green_end([1], 45.0) == 75.0 and p.green_end([0, 1], 45.0) == 75.0
    both = Program(((20.0, "Gg"), (10.0, "GG"), (5.0, "yy"), (30.0, "rr")))   # green on over two phases
    assert both.green_end([1], 5.0) == 30.0 and both.green_end([0], 25.0) == 30.0


def test_a_yielding_green_lets_its_queue_through_as_the_green_ends(tmp_path, cross_net):
    """A left turn through a yielding green g against an opposing stream that leaves no gap: its
    queue goes one vehicle a cycle, the one waiting inside the junction as the green ends (SUMO's
    waiting position), so a queue of such turns grows where the saturation headway would clear it."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.queues import SNEAKERS
    from sumo_scendiff.fill.travel import TravelTimes
    from sumo_scendiff.map.network import Network
    net = Network.load(cross_net)
    times = TravelTimes(net)
    link = times.link_of("wc", "cn")
    program = times.light(link)
    assert link.foes and program is not None
    routes = tmp_path / "left.rou.xml"
    routes.write_text("<routes>" + "".join(
        f'<vehicle id="l{i}" depart="{i}" departSpeed="max"><route edges="wc cn"/></vehicle>' for i in range(8))
        + '<flow id="opp" begin="0" end="3600" period="1.5" departSpeed="max"><route edges="ec cw"/></flow>'
        "</routes>")
    begin = 600.0
    t, ends = 7.0 + times.edge("wc")[0] + 1.0, []      # all eight at the line by then
    while True:
        end = program.green_end(link.indices, program.next_green(link.indices, t))
        if end > begin:
            break
        ends.append(end)
        t = end + 0.1
    est = DemandEstimate.at(net, [str(routes)], begin=begin)
    waiting = [v for v in est.en_route if v.id.startswith("l") and v.edges[0] == "wc"]
    assert len(waiting) == 8 - SNEAKERS * link.lanes * len(ends) and all(v.waiting for v in waiting)
    assert 3 <= len(ends) <= 7


def _approach_counts(tmp_path, net_path: str, flows: dict, edge: str) -> tuple[list[int], list[int]]:
    """Vehicles on ``edge`` every minute from 5 to 20 minutes, in SUMO (libsumo, seed 1) running the
    ``flows`` ((from, to) -> veh/s, random arrivals) and in the estimate; (estimate, SUMO)."""
    import libsumo

    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.map.network import Network
    routes = tmp_path / "flows.rou.xml"
    routes.write_text("<routes>" + "".join(
        f'<flow id="{a}{b}" begin="0" end="1500" probability="{q}" departSpeed="max"><route edges="{a} {b}"/></flow>'
        for (a, b), q in flows.items()) + "</routes>")
    net = Network.load(net_path)
    libsumo.start(["sumo", "-n", net_path, "-r", str(routes), "--seed", "1", "--no-step-log", "--no-warnings"])
    sumo, est = [], []
    try:
        for t in range(300, 1201, 60):
            libsumo.simulationStep(t)
            sumo.append(sum(libsumo.vehicle.getRoadID(v) == edge for v in libsumo.vehicle.getIDList()))
            est.append(DemandEstimate.at(net, [str(routes)], float(t)).on_edge.get(edge, 0))
    finally:
        libsumo.close()
    return est, sumo


def test_a_left_turns_queue_against_oncoming_traffic_is_as_long_as_sumos(tmp_path, cross2_net):
    """Left turns through a busy oncoming stream (two lanes each way, a fixed light): SUMO's
    approach holds a standing queue of them; the estimate's count on it is SUMO's within 25 % (each
    vehicle waiting Adams' delay grown by the queue's 1 / (1 - x) on its own, before, filled the
    approach to 1.6 times SUMO's)."""
    est, sumo = _approach_counts(tmp_path, cross2_net, {("wc", "cn"): 0.06, ("ec", "cw"): 0.4, ("wc", "ce"): 0.1}, "wc")
    assert np.mean(est) == pytest.approx(np.mean(sumo), rel=0.25), (est, sumo)


def test_expected_durations_of_an_actuated_program():
    """Without traffic each actuated green ends at its minDur (amber keeps its time); a phase's
    green grows with its lanes' flow and stays within maxDur."""
    from sumo_scendiff.fill.actuated import expected_durations
    states, durations = ["Gr", "yr", "rG", "ry"], [40.0, 3.0, 40.0, 3.0]
    bounds = [(5.0, 50.0), (3.0, 3.0), (5.0, 50.0), (3.0, 3.0)]
    lanes = {"w_0": {0: 0.0}, "s_0": {1: 0.0}}
    assert expected_durations(states, durations, bounds, lanes, 0.5) == (5.0, 3.0, 5.0, 3.0)
    greens = [expected_durations(states, durations, bounds, {"w_0": {0: q}, "s_0": {1: 0.05}}, 0.5)[0]
              for q in (0.1, 0.2, 0.3, 0.45)]
    assert greens == sorted(greens) and greens[0] > 5.0 and greens[-1] == 50.0


def test_an_actuated_light_runs_its_phases_as_sumo_does(tmp_path):
    """Under a busy west-east and a light south-north stream, the cycle and each green of an
    actuated light (SUMO's gap control) are what SUMO runs, not its programmed durations."""
    import libsumo

    from sumo_scendiff.fill.programs import signal_programs
    from sumo_scendiff.fill.travel import TravelTimes
    from sumo_scendiff.map.network import Network
    from .conftest import netconvert
    nodes = ('<node id="c" x="0" y="0" type="traffic_light"/><node id="w" x="-200" y="0"/>'
             '<node id="e" x="200" y="0"/><node id="s" x="0" y="-200"/><node id="n" x="0" y="200"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="1" speed="13.89"/>'
                    for a, b in (("w", "c"), ("c", "w"), ("e", "c"), ("c", "e"),
                                 ("s", "c"), ("c", "s"), ("n", "c"), ("c", "n")))
    path = netconvert(nodes, edges, str(tmp_path / "act.net.xml"), "--tls.default-type", "actuated")
    flows = {("wc", "ce"): 0.25, ("ec", "cw"): 0.25, ("sc", "cn"): 0.03, ("nc", "cs"): 0.03}
    routes = tmp_path / "act.rou.xml"
    routes.write_text("<routes>" + "".join(
        f'<flow id="{a}{b}" begin="0" end="1500" probability="{q}" departSpeed="max"><route edges="{a} {b}"/></flow>'
        for (a, b), q in flows.items()) + "</routes>")
    [(tls, program)] = signal_programs([path]).items()
    assert not program.fixed and program.bounds
    est = TravelTimes(Network.load(path), flows=flows)._programs[tls]
    libsumo.start(["sumo", "-n", path, "-r", str(routes), "--seed", "3", "--no-step-log", "--no-warnings"])
    spans: dict[int, list[float]] = {}
    try:
        phase, since = libsumo.trafficlight.getPhase(tls), 0.0
        while libsumo.simulation.getTime() < 1500:
            libsumo.simulationStep()
            t, now = libsumo.simulation.getTime(), libsumo.trafficlight.getPhase(tls)
            if now != phase:
                if t > 300:
                    spans.setdefault(phase, []).append(t - since)
                phase, since = now, t
    finally:
        libsumo.close()
    sumo = [sum(spans[i]) / len(spans[i]) for i in range(len(program.phases))]
    mine = [d for d, _ in est.phases]
    assert sum(mine) == pytest.approx(sum(sumo), rel=0.15), (mine, sumo)
    assert sum(d for d, _ in program.phases) > 1.5 * sum(sumo)       # the programmed cycle is not it
    for (d, st), s in zip(est.phases, sumo):
        assert d == pytest.approx(s, abs=max(2.0, 0.2 * s)), (mine, sumo)


def test_a_queue_stands_on_the_lanes_that_lead_to_its_turn(tmp_path, left_lane_net):
    """Left turns at red on a two-lane approach whose left lane alone turns left: the approach
    holds one lane of them, the rest stand back on the edge before it, as in SUMO (an edge's whole
    storage held twice as many there and none upstream)."""
    import libsumo

    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.travel import TravelTimes
    from sumo_scendiff.map.network import Network
    net = Network.load(left_lane_net)
    lefts = [ln.getIndex() for ln in net.sumo_net.getEdge("wc").getLanes()
             if any(c.getTo().getID() == "cn" for c in ln.getOutgoing())]
    assert lefts == [1]
    routes = tmp_path / "left.rou.xml"
    routes.write_text("<routes>" + "".join(
        f'<vehicle id="l{i}" depart="{2 * i}" departSpeed="max"><route edges="w0w wc cn"/></vehicle>'
        for i in range(16)) + "</routes>")
    times = TravelTimes(net)
    link = times.link_of("wc", "cn")
    begin = times.light(link).next_green(link.indices, 30.0) - 1.0    # the queue at its longest
    est = DemandEstimate.at(net, [str(routes)], begin)
    libsumo.start(["sumo", "-n", left_lane_net, "-r", str(routes), "--seed", "1", "--no-step-log", "--no-warnings"])
    try:
        libsumo.simulationStep(begin)
        sumo = {e: sum(libsumo.vehicle.getRoadID(v) == e for v in libsumo.vehicle.getIDList()) for e in ("wc", "w0w")}
    finally:
        libsumo.close()
    one_lane = net.sumo_net.getEdge("wc").getLength() / 7.5
    assert est.on_edge["wc"] <= one_lane + 1 and sumo["wc"] <= one_lane + 1, (est.on_edge, sumo)
    for e in ("wc", "w0w"):
        assert abs(est.on_edge.get(e, 0) - sumo[e]) <= 2, (e, est.on_edge, sumo)


def test_a_minor_roads_queue_grows_when_the_major_stream_leaves_it_too_few_gaps(tmp_path, priority_net):
    """A minor road crossing a major one (0.2 veh/s each way) at 0.1 veh/s, more than the gaps let
    across: SUMO's queue on the minor approach grows and fills it; the estimate's, one vehicle let
    through per gap of MINOR_GAP s, as well (within 25 % of SUMO's over 15 minutes). Each vehicle
    waiting its own grown Adams' delay instead held a third of SUMO's queue."""
    est, sumo = _approach_counts(tmp_path, priority_net, {("wc", "ce"): 0.2, ("ec", "cw"): 0.2, ("sc", "cn"): 0.1}, "sc")
    assert np.mean(sumo) > 20 and np.mean(est) == pytest.approx(np.mean(sumo), rel=0.25), (est, sumo)
