"""The demand estimate's clock (fill/travel.py): the lights' programs and load, the junctions'
internal lanes, vTypes and departures, on the project's generated networks."""
from __future__ import annotations

import os

import pytest

NETS = os.path.join(os.path.dirname(__file__), "..", "networks")
NET4 = os.path.join(NETS, "grid4x4_2lane_tls.net.xml")


def test_green_shares_and_an_additional_program(tmp_path):
    """A light's program gives each link its green share (amber half); an additional file's
    program replaces the network's, as in SUMO."""
    from sumo_scendiff.fill.travel import green_shares
    a = tmp_path / "a.add.xml"
    a.write_text('<additional><tlLogic id="J" type="static" programID="1" offset="0">'
                 '<phase duration="30" state="Gr"/><phase duration="4" state="yr"/>'
                 '<phase duration="26" state="rG"/></tlLogic></additional>')
    cycle, green = green_shares([str(a)])["J"]
    assert cycle == 60 and green == pytest.approx([32 / 60, 26 / 60])
    b = tmp_path / "b.add.xml"
    b.write_text(a.read_text().replace('duration="26"', 'duration="56"'))
    assert green_shares([str(a), str(b)])["J"][0] == 90


def _signalised_pairs(net):
    """(edge, next) pairs of the network whose connections a traffic light controls, straight and turning."""
    straight, turn = [], []
    for e in net.sumo_net.getEdges():
        for nxt, conns in e.getOutgoing().items():
            if conns and conns[0].getTLSID():
                (straight if conns[0].getDirection() == "s" else turn).append((e.getID(), nxt.getID()))
    return straight, turn


def test_a_lights_wait_is_webster_and_grows_with_its_load():
    """Unloaded, the wait at a light is Webster's C (1 - λ)² / 2; the demand's flow through the link
    lengthens it (1 / (1 - λx)), never without bound."""
    from sumo_scendiff.fill.travel import SATURATION_FLOW, X_MAX, TravelTimes
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    (e, nxt), *_ = _signalised_pairs(net)[0]
    free = TravelTimes(net)
    link = free.link_of(e, nxt)
    assert 0 < link.green < 1 and link.cycle > 0
    wait, _ = free.link(e, nxt)
    assert wait == pytest.approx(link.cycle * (1 - link.green) ** 2 / 2)
    half = TravelTimes(net, flows={(e, nxt): 0.5 * SATURATION_FLOW * link.lanes * link.green})
    over = TravelTimes(net, flows={(e, nxt): 10 * SATURATION_FLOW * link.lanes})
    w_half, w_over = half.link(e, nxt)[0], over.link(e, nxt)[0]
    assert wait < w_half < w_over
    assert w_half == pytest.approx(wait / (1 - 0.5 * link.green))
    assert w_over == pytest.approx(wait / (1 - X_MAX * link.green))


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
                 '</additional>')
    d = vtype_drivers([str(f)])
    assert d["slow"].speed_factor == pytest.approx(0.8) and d["slow"].accel == 1.5
    assert d["slow"].decel == DEFAULT_DRIVER.decel
    assert d["bus"].max_speed < DEFAULT_DRIVER.max_speed and d["bus"].accel < DEFAULT_DRIVER.accel
    assert d["mix"] == d["slow"]
    assert d["slow"].cruise(13.89) < DEFAULT_DRIVER.cruise(13.89)


def test_depart_pos_and_speed_in_the_estimate(tmp_path):
    """A vehicle entering halfway along its edge (departPos) is through it sooner than one entering
    at its start; one entering at speed (departSpeed="max") sooner than one from standing."""
    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    e = max(net.sumo_net.getEdges(), key=lambda x: x.getLength())
    routes = tmp_path / "d.rou.xml"

    def remaining(attrs: str) -> float:
        routes.write_text(f'<routes><vehicle id="a" depart="0" {attrs}><route edges="{e.getID()}"/></vehicle></routes>')
        [v] = DemandEstimate.at(net, [str(routes)], begin=1.0).en_route
        return v.travel - v.since, v.offset
    base, off = remaining("")
    half, off_half = remaining(f'departPos="{e.getLength() / 2:.2f}"')
    moving, _ = remaining('departSpeed="max"')
    assert off == 0 and off_half == pytest.approx(e.getLength() / 2, abs=0.01)
    assert half < base and moving < base
