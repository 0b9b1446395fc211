"""Networks as netconvert builds them from OpenStreetMap: a zero-length connection at joined
junctions is an internal lane written as two equal points (osmWebWizard's Helsinki centre has nine).
Such a lane has a footprint like any other, so a query finds it and a distance to it is a number."""
from __future__ import annotations

import os
import re
import subprocess

import pytest

from sumo_scendiff.map.locations import LocationError, window_at
from sumo_scendiff.map.network import Network


@pytest.fixture(scope="module")
def degenerate(tmp_path_factory) -> tuple[Network, str]:
    """netgenerate's 2x2 grid with one internal car lane's shape made two equal points, as netconvert
    writes OSM's zero-length connections (``shape="351.60,378.26 351.60,378.26"``)."""
    import sumo
    d = tmp_path_factory.mktemp("degenerate")
    out = str(d / "grid.net.xml")
    subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "netgenerate"), "--grid", "--grid.number", "2",
                    "--grid.length", "100", "-o", out], check=True, capture_output=True)
    text = open(out).read()
    m = re.search(r'(<lane id="(:[^"]+)" [^>]*shape=")([-\d.]+),([-\d.]+)[^"]*"', text)
    assert m, "netgenerate's grid has internal lanes"
    point = f"{m.group(3)},{m.group(4)}"
    text = text.replace(m.group(0), f'{m.group(1)}{point} {point}"', 1)
    with open(out, "w") as f:
        f.write(text)
    return Network.load(out), m.group(2)


def test_a_zero_length_lane_has_a_footprint(degenerate):
    net, lane_id = degenerate
    lane = net.lanes[net.lane_index[lane_id]]
    assert lane.car and not lane.polygon.is_empty
    assert all(not ln.polygon.is_empty for ln in net.lanes)


def test_a_far_centre_names_the_distance_to_the_nearest_lane(degenerate):
    net, _ = degenerate
    with pytest.raises(LocationError) as e:
        window_at(net, 3200.0, 0.0)
    assert "nan" not in str(e.value)
    assert re.search(r"nearest car lane 3\d\d\d m away", str(e.value)), str(e.value)
