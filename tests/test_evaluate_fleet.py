"""evaluate's scenes with the scenario's fleet (evaluate/delivered.py): the sizes SUMO gets when run
seeds a generated scene into a scenario with a demand, read from the demand by real SUMO."""
from __future__ import annotations

import numpy as np

from sumo_scendiff.evaluate.delivered import scenario_fleet, with_fleet
from sumo_scendiff.evaluate.jsd import vehicle_features
from sumo_scendiff.map.network import Network

ROUTES = """<routes>
  <vType id="car" length="5" width="1.8"/>
  <vType id="lorry" vClass="truck" length="12" width="2.5"/>
  <flow id="a" type="car" begin="0" end="100" number="9" from="wc" to="ce"/>
  <flow id="b" type="lorry" begin="0" end="100" number="1" from="sc" to="cn"/>
</routes>
"""


def test_generated_boxes_take_the_scenarios_vtypes(tmp_path, cross_net, cross_scene):
    routes = tmp_path / "demand.rou.xml"
    routes.write_text(ROUTES)
    net = Network.load(cross_net)
    fleet = scenario_fleet(net, str(routes))
    assert fleet is not None and set(fleet.share) == {"car", "lorry"}
    assert abs(fleet.share["car"] - 0.9) < 1e-9
    scenes = [cross_scene(net) for _ in range(6)]
    drawn = [s.boxes[:, 3:5].copy() for s in scenes]
    out = with_fleet(scenes, fleet, net, seed=0)
    sizes = {(round(float(b[3]), 3), round(float(b[4]), 3)) for s in out for b in s.boxes}
    assert sizes <= {(5.0, 1.8), (12.0, 2.5)} and (5.0, 1.8) in sizes   # what SUMO's vehicles would be
    assert all(np.array_equal(s.boxes[:, 3:5], d) for s, d in zip(scenes, drawn))   # copies: the model's kept
    assert with_fleet(scenes, fleet, net, seed=0)[0].boxes.tolist() == out[0].boxes.tolist()   # seeded
    lengths = vehicle_features(out, net)["length"]
    assert set(np.round(lengths, 3)) <= {5.0, 12.0}


def test_no_demand_no_fleet(tmp_path, cross_net, cross_scene):
    net = Network.load(cross_net)
    assert scenario_fleet(net, None) is None
    scenes = [cross_scene(net)]
    assert with_fleet(scenes, None, net, seed=0)[0] is scenes[0]
