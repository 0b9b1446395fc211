"""--area and the network's edge: an area on the network's boundary (its edges' centre lines) means
the whole network, the outer streets' lanes half a lane width beyond it included; a side inside the
network is kept exactly (fill/tiles.whole_area). Real SUMO, real model, a tiny grid."""
from __future__ import annotations

import json
import subprocess

import pytest

# the grid's perimeter, anticlockwise: every vehicle of the demand drives the outer streets
RING = ["A0B0", "B0C0", "C0C1", "C1C2", "C2B2", "B2A2", "A2A1", "A1A0"]


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    from sumo_scendiff.core.tools import sumo_binary
    d = tmp_path_factory.mktemp("area")
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
                    "-o", str(d / "grid.net.xml")], check=True, capture_output=True)
    (d / "ring.rou.xml").write_text(f'<routes><route id="ring" edges="{" ".join(RING)}"/>'
                                    '<flow id="f" route="ring" begin="0" end="300" period="4"/></routes>')
    (d / "ring.sumocfg").write_text(
        '<configuration><input><net-file value="grid.net.xml"/><route-files value="ring.rou.xml"/></input>'
        '</configuration>')
    return d


def test_a_side_on_the_boundary_reaches_the_outer_lanes_and_an_inner_side_stays(grid):
    from sumo_scendiff.fill.tiles import whole_area
    from sumo_scendiff.map.network import Network
    net = Network.load(str(grid / "grid.net.xml"))
    assert net.sumo_net.getBoundary() == [0.0, 0.0, 200.0, 200.0]
    x0, y0, x1, y1 = whole_area(net, (0.0, 0.0, 200.0, 200.0))
    # the outer streets' lanes (centre lines at -1.6 and 201.6, 3.2 m wide) lie inside
    assert x0 <= -3.2 and y0 <= -3.2 and x1 >= 203.2 and y1 >= 203.2
    assert whole_area(net, (50.0, 50.0, 150.0, 150.0)) == (50.0, 50.0, 150.0, 150.0)
    assert whole_area(net, (0.0, 50.0, 150.0, 300.0)) == (x0, 50.0, 150.0, 300.0)
    assert whole_area(net, None) is None


@pytest.mark.slow
@pytest.mark.parametrize("start", [[], ["--demand-estimate"]], ids=["sumo", "estimate"])
def test_a_fill_of_the_boundary_drops_no_vehicle_of_the_outer_streets(grid, start):
    """Both starts: SUMO's own run (what it has in the area) and the estimate."""
    from sumo_scendiff.fill.__main__ import get_options, main
    out = grid / f"o{len(start)}"
    assert main(get_options(["-c", str(grid / "ring.sumocfg"), "--begin", "150", "--area", "0,0,200,200",
                             "-o", str(out), *start])) == 0
    doc = json.loads((out / "fill.json").read_text())
    vehicles = doc["density"]["vehicles"]
    kept = vehicles["in_area"] if not start else vehicles["placed"]
    assert vehicles["outside"] == 0 and kept > 10
    assert (doc["density"].get("start") == "sumo") == (not start)
    xy = [(a["x"], a["y"]) for a in doc["agents"]]
    # kept on the outer streets, centres beyond the boundary: the lanes at -1.6 and 201.6
    assert sum(min(x, y) < 0 or max(x, y) > 200 for x, y in xy) > 5
