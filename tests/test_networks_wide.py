"""The networks of the ``train_wide`` split (networks/_wide.py): shaped like the real cities the
project is judged on, and added beside the ``train`` split without changing it."""
import json
import os

import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..", "networks")
WIDE = ("osm_irregular.net.xml", "osm_suburb.net.xml", "arterial_lights.net.xml", "dense_urban_grid.net.xml")


@pytest.fixture(scope="module")
def splits():
    with open(os.path.join(ROOT, "splits.json")) as f:
        return json.load(f)


def test_train_wide_is_train_plus_the_new_networks(splits):
    assert splits["train_wide"] == splits["train"] + list(WIDE)
    assert not set(WIDE) & set(splits["train"])


@pytest.fixture(scope="module")
def nets():
    import sumolib
    return {name: sumolib.net.readNet(os.path.join(ROOT, name)) for name in WIDE}


def _car_edges(net):
    return [e for e in net.getEdges() if e.getFunction() == "" and e.allows("passenger")]


def _car_lanes(edge):
    return sum(lane.allows("passenger") for lane in edge.getLanes())


def test_streets_as_in_the_cities(nets):
    """Each network: 30 km/h streets and 50 km/h roads, right-before-left and priority junctions,
    one-way streets, 1-lane streets beside multi-lane roads, edges mostly under 100 m."""
    import numpy as np
    for name, net in nets.items():
        edges = _car_edges(net)
        speeds = {round(e.getSpeed(), 2) for e in edges}
        assert {8.33, 13.89} <= speeds, name
        types = {n.getType() for n in net.getNodes()}
        assert {"right_before_left", "priority", "traffic_light"} <= types, name
        ends = {(e.getFromNode().getID(), e.getToNode().getID()) for e in edges}
        assert any((b, a) not in ends for a, b in ends), f"{name}: no one-way street"
        lanes = {_car_lanes(e) for e in edges}
        assert 1 in lanes and max(lanes) >= 2, name
        assert np.median([e.getLength() for e in edges]) < 100, name


def test_lights_of_both_kinds_and_turn_pockets(nets):
    """Actuated and fixed-time lights in the set (and in the arterial network itself); a lane
    added before a light (a split edge whose second part has more lanes)."""
    import xml.etree.ElementTree as ET
    kinds = {}
    for name in WIDE:
        root = ET.parse(os.path.join(ROOT, name)).getroot()
        kinds[name] = {t.get("type") for t in root.iter("tlLogic")}
    assert kinds["arterial_lights.net.xml"] == {"actuated", "static"}
    net = nets["arterial_lights.net.xml"]
    pockets = [e for e in _car_edges(net) if e.getToNode().getType() == "traffic_light"
               and len(e.getIncoming()) == 1 and _car_lanes(e) > _car_lanes(next(iter(e.getIncoming())))]
    assert pockets
