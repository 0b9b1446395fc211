"""SUMO's own edgeData output read back as vehicles per km of car lane, and bad files named."""
from __future__ import annotations

import subprocess

import numpy as np
import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.core.tools import sumo_binary
from sumo_scendiff.map.edgedata import EdgeData, EdgeDataError
from sumo_scendiff.map.network import Network


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
