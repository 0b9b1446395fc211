"""SUMO's own edgeData output read back as vehicles per km of car lane, and bad files named."""
from __future__ import annotations

import subprocess

import numpy as np
import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.core.tools import sumo_binary
from sumo_scendiff.map.edgedata import EdgeData, EdgeDataError
from sumo_scendiff.map.network import Network

from .conftest import netconvert


@pytest.fixture(scope="module")
def measured(cross_net, tmp_path_factory):
    """Real SUMO: a flow west -> east through the crossing, edgeData every 60 s."""
    d = tmp_path_factory.mktemp("edgedata")
    (d / "r.rou.xml").write_text('<routes><flow id="f" begin="0" end="300" period="4" from="wc" to="ce" '
                                 'departSpeed="max"/></routes>')
    (d / "m.add.xml").write_text(f'<additional><edgeData id="m" period="60" file="{d / "out.xml"}"/></additional>')
    subprocess.run([sumo_binary(), "-n", cross_net, "-r", str(d / "r.rou.xml"), "-a", str(d / "m.add.xml"),
                    "--end", "300", "--no-step-log", "true"], check=True, capture_output=True)
    return Network.load(cross_net), str(d / "out.xml")


def test_the_window_density_is_what_sumo_measured(measured):
    net, path = measured
    data = EdgeData.read(path, net)
    iv = data.at(150.0)
    assert (iv.begin, iv.end) == (120.0, 180.0)
    assert iv.density["wc"] > 5.0 and iv.density["sc"] == 0.0      # the flow's road, an empty one
    on_road = data.window_density(net, Window(-100.0, 0.0, 0.0), 150.0)
    assert on_road == pytest.approx(np.mean([iv.density["wc"], iv.density["cw"]]), rel=0.05)


def test_an_edge_sumo_did_not_write_is_empty(measured, tmp_path):
    """SUMO's --edgedata-output writes only the edges a vehicle used: a window none of whose edges
    the file lists is empty (0 veh/km), not unknown (the model's own level filled such windows)."""
    net, path = measured
    data = EdgeData.read(path, net)
    south = Window(0.0, -100.0, np.pi / 2)
    assert data.window_density(net, south, 150.0) == 0.0                 # listed, at 0 veh/km
    import re
    text = open(path).read()
    only_flow = re.sub(r'<edge id="(?!wc"|ce")[^"]*"[^>]*/>', "", text)  # as SUMO writes it: used edges
    thin = tmp_path / "used.xml"
    thin.write_text(only_flow)
    used = EdgeData.read(str(thin), net)
    assert set(used.at(150.0).density) == {"wc", "ce"}
    assert used.window_density(net, south, 150.0) == 0.0
    assert used.window_density(net, Window(-100.0, 0.0, 0.0), 150.0) > 2.0


def test_an_edge_with_a_bike_lane_counts_its_vehicles_on_its_car_lane(tmp_path):
    """SUMO's laneDensity is the edge's density over its lanes open to vehicles: on a road with a
    bike lane, half. The density per km of car lane is the edge's, whichever attribute the file
    gives (taken per lane, a city whose roads have bike lanes was filled with half its traffic)."""
    net_path = netconvert('<node id="a" x="0" y="0"/><node id="b" x="300" y="0"/>',
                          '<edge id="ab" from="a" to="b" numLanes="1" bikeLaneWidth="1.5"/>',
                          str(tmp_path / "bike.net.xml"))
    (tmp_path / "r.rou.xml").write_text('<routes><flow id="f" begin="0" end="300" period="3" from="ab" '
                                        'to="ab" departSpeed="max"/></routes>')
    subprocess.run([sumo_binary(), "-n", net_path, "-r", str(tmp_path / "r.rou.xml"), "--end", "300",
                    "--edgedata-output", str(tmp_path / "out.xml"), "--no-step-log", "true"],
                   check=True, capture_output=True)
    net = Network.load(net_path)
    assert [ln.car for ln in net.lanes if ln.edge == "ab"].count(True) == 1 and len(
        [ln for ln in net.lanes if ln.edge == "ab"]) == 2
    text = open(tmp_path / "out.xml").read()
    import re
    density = float(re.search(r' density="([^"]+)"', text).group(1))
    assert float(re.search(r' laneDensity="([^"]+)"', text).group(1)) == pytest.approx(density / 2, abs=0.01)
    only_lane = tmp_path / "lane.xml"
    only_lane.write_text(re.sub(r' density="[^"]*"', "", text))
    for path in (tmp_path / "out.xml", only_lane):
        got = EdgeData.read(str(path), net).window_density(net, Window(150.0, 0.0, 0.0), 150.0)
        assert got == pytest.approx(density, rel=0.05), path


def test_sampled_seconds_alone_give_sumos_lane_density(measured, tmp_path):
    """A file without density attributes (e.g. written by another tool) gives the same densities
    from sampledSeconds over the interval and the edge's lane-kilometres."""
    import re
    net, path = measured
    text = re.sub(r' (?:laneDensity|density|overlapDensity)="[^"]*"', "", open(path).read())
    bare = tmp_path / "bare.xml"
    bare.write_text(text)
    full, thin = EdgeData.read(path, net).at(150.0), EdgeData.read(str(bare), net).at(150.0)
    for edge, d in full.density.items():
        assert thin.density[edge] == pytest.approx(d, rel=0.03, abs=0.05)


def test_bad_edgedata_files_are_one_line(measured, tmp_path):
    net, path = measured
    data = EdgeData.read(path, net)
    with pytest.raises(EdgeDataError, match=r"no interval covers t = 900 s \(intervals 0-300 s\)"):
        data.at(900.0)
    bad = tmp_path / "routes.xml"
    bad.write_text("<routes><vehicle id='a' depart='0'/></routes>")
    with pytest.raises(EdgeDataError, match="not a SUMO edgeData file"):
        EdgeData.read(str(bad), net)
    other = tmp_path / "other.xml"
    other.write_text('<meandata><interval begin="0" end="60"><edge id="nowhere" density="3"/></interval></meandata>')
    with pytest.raises(EdgeDataError, match="names no edge of the network"):
        EdgeData.read(str(other), net)
    with pytest.raises(EdgeDataError, match="no such file"):
        EdgeData.read(str(tmp_path / "missing.xml"), net)


def test_human_readable_times_are_read(measured, tmp_path):
    """SUMO's --human-readable-time writes the intervals as h:m:s: the same intervals."""
    import re
    net, path = measured
    text = open(path).read()
    hms = re.sub(r'(begin|end)="([\d.]+)"',
                 lambda m: f'{m.group(1)}="0:{int(float(m.group(2))) // 60:02d}:{int(float(m.group(2))) % 60:02d}"', text)
    (tmp_path / "hms.xml").write_text(hms)
    iv = EdgeData.read(str(tmp_path / "hms.xml"), net).at(150.0)
    assert (iv.begin, iv.end) == (120.0, 180.0) and iv.density == EdgeData.read(path, net).at(150.0).density


def test_a_lanedata_file_gives_the_edges_densities(cross_net, tmp_path):
    """SUMO's laneData (per lane) read as its edgeData: the same density per km of car lane."""
    (tmp_path / "r.rou.xml").write_text('<routes><flow id="f" begin="0" end="300" period="4" from="wc" to="ce" '
                                        'departSpeed="max"/></routes>')
    (tmp_path / "m.add.xml").write_text(f'<additional><edgeData id="e" period="60" file="{tmp_path / "e.xml"}"/>'
                                        f'<laneData id="l" period="60" file="{tmp_path / "l.xml"}"/></additional>')
    subprocess.run([sumo_binary(), "-n", cross_net, "-r", str(tmp_path / "r.rou.xml"), "-a",
                    str(tmp_path / "m.add.xml"), "--end", "300", "--no-step-log", "true"],
                   check=True, capture_output=True)
    net = Network.load(cross_net)
    edges, lanes = EdgeData.read(str(tmp_path / "e.xml"), net).at(150.0), EdgeData.read(str(tmp_path / "l.xml"), net).at(150.0)
    assert edges.density["wc"] > 5.0
    assert lanes.density == pytest.approx(edges.density, rel=0.01, abs=0.01)
