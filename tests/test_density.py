"""Traffic in traffic terms: density targets from flags, the host's level, vehicle counts; the
vehicles already in a window counted in run's summary."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.density import (
    DensityError,
    QUEUE_ZONE,
    host_density,
    parse_density,
    parse_vehicles,
    window_target,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.parametrize("text, want", [("25", 25.0), ("0", 0.0), ("133", 133.0), ("auto", "auto"), ("AUTO", "auto"), (None, None)])
def test_density_flag_values(text, want):
    assert parse_density(text) == want


@pytest.mark.parametrize("text", ["-1", "nan", "inf", "lots", "", "200"])
def test_bad_density_values_name_the_flag(text):
    with pytest.raises(DensityError, match="^--density: "):
        parse_density(text)


@pytest.mark.parametrize("text", ["-2", "2.5", "nan", "ten"])
def test_bad_vehicle_counts_name_the_flag(text):
    with pytest.raises(DensityError, match="^--vehicles: "):
        parse_vehicles(text)


def test_vehicles_become_a_density_over_the_windows_car_lanes(diagonal_net):
    net = Network.load(diagonal_net)
    w = Window(150.0, 150.0, 0.0)
    km = net.car_lane_km(w)
    assert window_target(net, w, vehicles=9) == pytest.approx(9 / km)
    assert window_target(net, w, density=30.0) == 30.0
    assert window_target(net, w, density="auto") is None            # no host, no edgeData: the prior
    assert window_target(net, Window(2000.0, 0.0, 0.0), vehicles=3) is None   # no car lane there


def test_the_hosts_own_level_around_a_window(tmp_path):
    """``auto`` with a host: the density around the window per class of road. A main road (priority
    10) carries a flow, the side road across it (priority 1) none: a window on the side street gets
    the side street's level, 0, not the crossing's; a window on the main road its level, vehicles on
    its lanes around over their km."""
    import libsumo
    import shapely

    from sumo_scendiff.core.tools import sumo_binary

    from .conftest import netconvert
    nodes = ('<node id="c" x="0" y="0" type="priority"/><node id="w" x="-300" y="0"/><node id="e" x="300" y="0"/>'
             '<node id="s" x="0" y="-300"/><node id="n" x="0" y="300"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="1" speed="13.89" priority="{p}"/>'
                    for a, b, p in (("w", "c", 10), ("c", "w", 10), ("e", "c", 10), ("c", "e", 10),
                                    ("s", "c", 1), ("c", "s", 1), ("n", "c", 1), ("c", "n", 1)))
    path = netconvert(nodes, edges, str(tmp_path / "two.net.xml"))
    net = Network.load(path)
    rou = tmp_path / "r.rou.xml"
    rou.write_text('<routes><flow id="f" begin="0" end="200" period="3" from="wc" to="ce"/></routes>')
    libsumo.start([sumo_binary(), "-n", path, "-r", str(rou), "--no-step-log", "true"])
    try:
        for _ in range(90):
            libsumo.simulationStep()
        side = host_density(libsumo, net, Window(0.0, 120.0, 1.5708), radius=200.0, zone=0.0)
        main = host_density(libsumo, net, Window(-120.0, 0.0, 0.0), radius=200.0, zone=0.0)
        circle = shapely.Point(-120.0, 0).buffer(200.0)
        lanes = [i for i in net.car_lane_ids if net.lanes[i].edge in ("wc", "cw", "ec", "ce")]
        n = sum(libsumo.vehicle.getLaneID(v) in {net.lanes[i].id for i in lanes}
                and shapely.Point(*libsumo.vehicle.getPosition(v)).within(circle) for v in libsumo.vehicle.getIDList())
        km = sum(shapely.length(shapely.intersection(net.lines[i], circle)) for i in lanes) / 1000
        assert n > 5 and main == pytest.approx(n / km, rel=1e-6)
        assert side == 0.0
    finally:
        libsumo.close()


def test_a_queue_before_the_stop_line_is_a_class_of_its_own(tmp_path):
    """A queue stands at a red light: the last QUEUE_ZONE m before a stop line are denser than the
    rest of the road, so a window at the light gets a higher level and a window mid-block a lower
    one than with ``zone=0``, where both read the road's average."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary

    from .conftest import netconvert
    nodes = ('<node id="c" x="0" y="0" type="traffic_light"/><node id="w" x="-400" y="0"/>'
             '<node id="e" x="400" y="0"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="1" speed="13.89"/>'
                    for a, b in (("w", "c"), ("c", "e")))
    path = netconvert(nodes, edges, str(tmp_path / "light.net.xml"))
    net = Network.load(path)
    rou = tmp_path / "r.rou.xml"
    rou.write_text('<routes><flow id="f" begin="0" end="200" period="6" from="wc" to="ce"/></routes>')
    libsumo.start([sumo_binary(), "-n", path, "-r", str(rou), "--no-step-log", "true"])
    try:
        libsumo.trafficlight.setRedYellowGreenState("c", "r" * len(libsumo.trafficlight.getRedYellowGreenState("c")))
        for _ in range(90):
            libsumo.simulationStep()
        assert libsumo.vehicle.getIDCount() >= 8
        at_light, mid = Window(-40.0, 0.0, 0.0), Window(-250.0, 0.0, 0.0)
        lvl = {z: (host_density(libsumo, net, at_light, radius=500.0, zone=z),
                   host_density(libsumo, net, mid, radius=500.0, zone=z)) for z in (0.0, QUEUE_ZONE)}
        assert lvl[QUEUE_ZONE][0] > 1.5 * lvl[0.0][0]           # the queue's level where the queue is
        assert lvl[QUEUE_ZONE][1] < lvl[0.0][1]                 # and not spread over the road
    finally:
        libsumo.close()


def test_run_counts_the_vehicles_already_in_the_window(cross_net, tmp_path):
    """With demand, the summary says how many vehicles were kept and how many generated, and their
    density over the window's car lanes."""
    rou = tmp_path / "r.rou.xml"
    rou.write_text('<routes><flow id="f" begin="7:00:00" end="7:05:00" period="3" from="wc" to="ce"/>'
                   '<flow id="g" begin="25200" end="25500" period="5" from="sc" to="cn"/></routes>')
    out = tmp_path / "out"
    # --begin is the time on SUMO's clock, as fill's and sumo's -b: a minute into the demand
    res = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-n", cross_net, "-r", str(rou), "--begin", "7:01:00",
                          "--center", "0,0", "--scenes", "1", "--rollout", "0", "-o", str(out)],
                         capture_output=True, text=True, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert res.returncode == 0, res.stderr
    summary = json.load(open(out / "run.json"))
    # after the step seeding it: SUMO's default 1 s, the step a demand without a configuration runs at
    assert json.load(open(out / "scene_000" / "scene.json"))["time"] == 25261.0
    assert summary["density"] == "auto (default with demand)"    # the host's level, not the model's
    row = summary["scenes"][0]
    assert row["existing_vehicles"] >= 3
    assert row["vehicles_in_window"] == row["existing_vehicles"] + row["placed"]
    km = Network.load(cross_net).car_lane_km(Window(0.0, 0.0, 0.0))
    assert row["density_veh_per_km"] == pytest.approx(row["vehicles_in_window"] / km, abs=0.01)
    assert " kept " in res.stdout.splitlines()[0] and f"beside {row['existing_vehicles']} vehicles kept" in res.stdout



def test_without_a_level_a_host_with_traffic_gives_its_own():
    """Neither --density nor --vehicles: inside a host simulation with traffic the host's level
    ("auto"), without one (or with a checkpoint that has no density condition) the model's own;
    "model" asks for the model's own with a host too; a level the user names is kept."""
    from sumo_scendiff.sim.density import MODEL, default_density
    assert default_density(None, None, host=True, has_density=True) == "auto"
    assert default_density(None, None, host=False, has_density=True) is None
    assert default_density(None, None, host=True, has_density=False) is None
    assert default_density(MODEL, None, host=True, has_density=True) is None
    assert default_density(12.0, None, host=True, has_density=True) == 12.0
    assert default_density(None, 5, host=True, has_density=True) is None     # window_target uses vehicles
    assert parse_density("model") == MODEL and parse_density(" Auto ") == "auto"
    with pytest.raises(DensityError, match="'auto' or 'model'"):
        parse_density("lots")


def test_the_divisor_leaves_out_the_junctions_internal_lanes(cross2_net):
    """A density's km is that of normal edges' car lanes (SUMO's edgeData measures no internal
    lane): a window on the crossing has internal lanes, and its km is the normal lanes' alone."""
    import shapely
    net = Network.load(cross2_net)
    w = Window(0.0, 0.0, 0.0)
    idx, km = net.car_lanes_in(w)
    internal = [net.lanes[i].internal for i in idx]
    assert any(internal)
    normal = sum(k for k, inside in zip(km, internal) if not inside)
    assert net.car_lane_km(w) == pytest.approx(normal) and net.car_lane_km(w) < km.sum()
    # per-edge densities over a region: weighted by the normal lanes' km, an unnamed edge empty
    region = shapely.box(-100, -100, 100, 100)
    some = net.lanes[next(i for i, inside in zip(idx, internal) if not inside)].edge
    lanes = {i: k for i, k in zip(*net.car_lanes_in_region(region, internal=False))}
    on_some = sum(k for i, k in lanes.items() if net.lanes[i].edge == some)
    assert net.region_density(region, {some: 30.0}) == pytest.approx(30.0 * on_some / sum(lanes.values()))


@pytest.mark.slow
def test_a_fills_density_is_what_sumos_edgedata_reports(tmp_path):
    """fill --density D on a small network, then stock SUMO's edgeData over the network's edges in
    the first second of the filled start: its density per km of car lane is D within 10 %."""
    import sumo
    import sumolib
    from sumolib.xml import parse

    from sumo_scendiff.fill.__main__ import get_options, main
    net_path = os.path.join(ROOT, "networks", "grid3x3_1lane.net.xml")
    out = tmp_path / "filled"
    assert main(get_options(["-n", net_path, "--density", "20", "-s", "0", "-o", str(out)])) == 0
    with open(out / "fill.json") as f:
        begin = json.load(f)["state_time"]
    ed = tmp_path / "ed.xml"
    subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "sumo"), "-c", str(out / "scenario.sumocfg"),
                    "--edgedata-output", str(ed), "-e", f"{begin + 1:g}", "--no-step-log", "--no-warnings"], check=True)
    net = sumolib.net.readNet(net_path)
    car_km = {e.getID(): sum(ln.getLength() for ln in e.getLanes() if ln.allows("passenger")) / 1000.0
              for e in net.getEdges(withInternal=False)}
    (interval,) = list(parse(str(ed), "interval"))
    # an edge's density is per km of the edge (all its lanes): times its length, its vehicles
    vehicles = sum(float(e.density) * net.getEdge(e.id).getLength() / 1000.0 for e in interval.edge if e.density)
    assert vehicles / sum(car_km.values()) == pytest.approx(20.0, rel=0.10)


def test_one_rule_for_a_window_without_car_lane(cross_net):
    """Vehicles per km (core.scene.per_km) is None where a window has no car lane, for a target
    (--vehicles N) and for a scene's density alike; the jam density is SUMO's default car at its
    minGap (sim.fleet)."""
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import per_km
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.density import JAM_DENSITY, window_target
    from sumo_scendiff.sim.fleet import DEFAULT_LENGTH, DEFAULT_MIN_GAP
    net = Network.load(cross_net)
    away, here = Window(5000.0, 5000.0, 0.0), Window(0.0, 0.0, 0.0)
    assert net.car_lane_km(away) == 0 and window_target(net, away, vehicles=6) is None
    assert window_target(net, here, vehicles=6) == pytest.approx(per_km(6, net.car_lane_km(here)))
    assert per_km(3, 0.0) is None and per_km(0, 0.5) == 0.0 and per_km(3, None) is None
    assert JAM_DENSITY == pytest.approx(1000.0 / (DEFAULT_LENGTH + DEFAULT_MIN_GAP))


def test_sumo_booleans_are_read_as_sumo_reads_them():
    from sumo_scendiff.core.sumo_xml import boolean
    assert [boolean(v) for v in ("true", "True", " 1", "yes", "on", "x")] == [True] * 6
    assert [boolean(v) for v in ("false", "0", "no", "off", "", None)] == [False] * 6
