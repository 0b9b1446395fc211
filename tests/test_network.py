"""Network loading, bad files, spatial queries."""
from __future__ import annotations

import gzip
import math
import shutil

import numpy as np
import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.map.network import Network, NetworkError

from .conftest import netconvert


@pytest.mark.parametrize("content, problem", [
    (None, "no such file"),
    (b"", "empty file"),
    (b"<routes><vehicle id='x'/></routes>", "not a SUMO network"),
])
def test_bad_files_name_the_file_and_the_problem(tmp_path, content, problem):
    path = tmp_path / "bad.net.xml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(NetworkError) as e:
        Network.load(str(path))
    assert str(path) in str(e.value) and problem in str(e.value)


def test_truncated_network(tmp_path, cross_net):
    data = open(cross_net, "rb").read()
    path = tmp_path / "trunc.net.xml"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(NetworkError, match="not a readable SUMO network"):
        Network.load(str(path))


def test_network_without_car_lanes(tmp_path):
    path = netconvert('<node id="a" x="0" y="0"/><node id="b" x="100" y="0"/>',
                      '<edge id="ab" from="a" to="b" allow="pedestrian" width="2"/>',
                      str(tmp_path / "ped.net.xml"))
    with pytest.raises(NetworkError, match="no lane a passenger car may use"):
        Network.load(path)


def test_gzipped_network_loads(tmp_path, cross_net):
    gz = tmp_path / "cross.net.xml.gz"
    with open(cross_net, "rb") as f, gzip.open(gz, "wb") as g:
        shutil.copyfileobj(f, g)
    net = Network.load(str(gz))
    assert net.name == "cross" and len(net.lanes) == len(Network.load(cross_net).lanes)


def test_queries_on_a_crossing(cross_net):
    net = Network.load(cross_net)
    assert any(ln.tls for ln in net.lanes) and any(ln.stop_line for ln in net.lanes)
    # right-hand traffic: the eastbound lane of w->c lies south of the x axis
    hit = net.lookup(-100.0, -1.6, 0.0)
    assert hit is not None and hit[0].edge == "wc"
    assert net.lookup(-100.0, -1.6, math.pi) is None or net.lookup(-100.0, -1.6, math.pi)[0].edge == "cw"
    assert net.on_drivable([[-100.0, -1.6], [-100.0, -30.0]]).tolist() == [True, False]
    diff = net.lane_heading_difference([[-100.0, -1.6], [-100.0, 1.6]], [0.0, 0.0])
    assert diff[0] == pytest.approx(0.0, abs=1e-6) and diff[1] == pytest.approx(0.0, abs=1e-6)
    diff = net.lane_heading_difference([[-100.0, -1.6], [-100, -40.0]], [math.pi / 2, 0.0])
    assert diff[0] == pytest.approx(math.pi / 2) and np.isnan(diff[1])
    assert net.has_road(Window(0.0, 0.0)) and not net.has_road(Window(150.0, 150.0, 0.0, 50.0))


def test_window_query_does_not_depend_on_network_size(cross_net):
    net = Network.load(cross_net)
    near = net.lanes_in(Window(-150.0, 0.0, 0.0, 20.0))
    assert {net.lanes[i].edge for i in near} <= {"wc", "cw"}


def test_heading_near_the_start_and_end_of_a_lane(cross_net):
    net = Network.load(cross_net)
    lane = next(ln for ln in net.lanes if ln.edge == "wc")
    start, end = lane.shape[0], lane.shape[-1]
    pts = [start + [0.2, 0.0], end - [0.2, 0.0]]
    assert net.lane_heading_difference(pts, [0.0, 0.0], radius=0.0) == pytest.approx([0.0, 0.0], abs=1e-6)


def test_networks_build_reproduces_the_repository_networks(tmp_path):
    """networks/build.py rebuilds every shipped .net.xml byte for byte (seed 42), and the training
    split names only networks it builds."""
    import json
    import os
    import subprocess
    import sys

    root = os.path.join(os.path.dirname(__file__), "..", "networks")
    res = subprocess.run([sys.executable, os.path.join(root, "build.py"), "-o", str(tmp_path), "-s", "42"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    built = sorted(p.name for p in tmp_path.glob("*.net.xml"))
    assert built == sorted(f for f in os.listdir(root) if f.endswith(".net.xml"))
    for name in built:
        with open(os.path.join(root, name), "rb") as f:
            assert (tmp_path / name).read_bytes() == f.read(), name
    splits = json.loads((tmp_path / "splits.json").read_text())
    assert set(splits["train_wide"]) | set(splits["heldout"]) == set(built)
    assert set(splits["train"]) < set(splits["train_wide"])
    assert not set(splits["train_wide"]) & set(splits["heldout"])


def test_car_lane_km_counts_the_lanes_inside_the_window(diagonal_net):
    """A one-way road of two 3.2 m lanes whose left edge runs along the window's diagonal: the lane
    centres lie 1.6 and 4.8 m right of it, so each is 2 * offset shorter than the diagonal."""
    import numpy as np

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.map.network import Network
    net = Network.load(diagonal_net)
    diagonal = 100.0 * np.sqrt(2)
    expected = (diagonal - 2 * 1.6) + (diagonal - 2 * 4.8)
    assert net.car_lane_km(Window(150.0, 150.0, 0.0)) == pytest.approx(expected / 1000.0, abs=0.001)
    assert net.car_lane_km(Window(150.0, 150.0, np.pi / 4)) == pytest.approx(0.2, abs=0.002)
    assert net.car_lane_km(Window(1000.0, 0.0, 0.0)) == 0.0
