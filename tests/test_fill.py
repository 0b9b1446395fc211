"""Whole-network fill (python -m sumo_scendiff.fill): real model, real SUMO, a small grid network."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import shapely

from sumo_scendiff.core.geometry import box_corners

from .conftest import netconvert

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

NET = os.path.join(os.path.dirname(__file__), "..", "networks", "grid3x3_1lane.net.xml")
NET4 = os.path.join(os.path.dirname(__file__), "..", "networks", "grid4x4_2lane_tls.net.xml")


def _fill(out, *extra, net=NET) -> dict:
    from sumo_scendiff.fill.__main__ import get_options, main
    assert main(get_options(["-n", net, "-o", str(out), *extra])) == 0
    with open(os.path.join(out, "fill.json")) as f:
        return json.load(f)


def _fail(capsys, *args) -> str:
    """The CLI's error on bad input: one line (-q: without the progress lines a fill logs as it works)."""
    from sumo_scendiff.fill.__main__ import get_options, main
    with pytest.raises(SystemExit) as e:
        main(get_options([*args, "-q"]))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.fixture(scope="module")
def filled(tmp_path_factory):
    out = tmp_path_factory.mktemp("fill") / "filled"
    return out, _fill(out, "-s", "3", "--workers", "1")


def _boxes(doc):
    return np.array([[a[k] for k in ("x", "y", "heading", "length", "width")] for a in doc["agents"]
                     if a["vehicle"]]).reshape(-1, 5)


def test_folder_is_complete_and_published(filled):
    out, doc = filled
    assert doc["format"] == "sumo-scendiff-fill" and doc["version"] == 1
    names = set(os.listdir(out))
    for f in ("fill.json", "state.xml.gz", "scenario.sumocfg", "start.rou.xml", "start.sumocfg", "fill.png",
              "inflow.rou.xml"):
        assert f in names
    assert not any(".partial" in n for n in os.listdir(os.path.dirname(out)))
    assert ".lock" not in names
    assert doc["density"]["kind"] == "prior" and doc["summary"]["vehicles"] > 0
    assert doc["inflow"]["file"] == "inflow.rou.xml" and doc["inflow"]["rate"]["probe"]["mean_speed_ms"] > 0
    # every car lane of the network lies in some tile's core
    assert sum(t["car_lane_km"] for t in doc["tiles"]) > 0


def test_inflow_rate_from_the_filled_network(filled):
    """fill.json records how the inflow's rate was found: the probe's measured speed (standing vehicles
    included, so below the free-flow speed of a network with junctions), the trip time from it, and the
    period Little's law gives, offered SUPPLY times over with both configurations capping the network at
    the filled number; the probe's replacements are the file's first departures."""
    from sumo_scendiff.fill.seed import SUPPLY
    out, doc = filled
    inflow = doc["inflow"]
    rate, probe = inflow["rate"], inflow["rate"]["probe"]
    assert probe["seconds"] > 0 and 0 < probe["mean_speed_ms"] < 13.9
    assert rate["measured_speed_ms"] == probe["mean_speed_ms"]
    assert rate["measured_trip_s"] == pytest.approx(rate["route_m"] / probe["mean_speed_ms"], abs=0.2)
    assert inflow["trip_s"] == max(rate["measured_trip_s"], rate["free_flow_trip_s"])
    n = doc["summary"]["vehicles"]
    assert inflow["period_s"] == pytest.approx(inflow["trip_s"] / n / SUPPLY, abs=2e-3)
    assert inflow["max_num_vehicles"] == n
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        assert f'<max-num-vehicles value="{n}"/>' in (out / cfg).read_text()
        assert f'<max-depart-delay value="{inflow["max_depart_delay_s"]:g}"/>' in (out / cfg).read_text()
    text = (out / "inflow.rou.xml").read_text()
    assert text.count("<vehicle ") == inflow["probe_departures"] == probe["replaced"]
    trips = [float(t.split('depart="')[1].split('"')[0]) for t in text.split("<trip ")[1:]]
    assert trips and min(trips) >= inflow["steady_from"] > doc["state_time"]


def test_inflow_surplus_waits_a_while_only(filled, tmp_path):
    """Stock SUMO on the folder for 450 s: the network stays at the filled number while the surplus
    offered beyond it waits to enter, and SUMO drops a vehicle that waited MAX_DEPART_DELAY_S, so the
    waiting list stays within what arrives in that time instead of growing with the hour."""
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.seed import MAX_DEPART_DELAY_S
    out, doc = filled
    summary = tmp_path / "summary.xml"
    run = subprocess.run([sumo_binary(), "-c", str(out / "scenario.sumocfg"), "--no-warnings",
                          "--end", f"{doc['state_time'] + 450:g}", "--summary-output", str(summary)],
                         check=False, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    steps = [line for line in summary.read_text().splitlines() if "<step " in line]
    value = lambda line, k: float(line.split(f'{k}="')[1].split('"')[0])   # noqa: E731
    waiting = [value(line, "waiting") for line in steps]
    assert max(waiting) <= MAX_DEPART_DELAY_S / doc["inflow"]["period_s"] + 2
    assert value(steps[-1], "discarded") > 0                 # the cap was reached: the surplus is dropped
    assert value(steps[-1], "running") >= 0.85 * doc["summary"]["vehicles"]


def test_inflow_period_follows_the_measured_speed(tmp_path):
    """Half the free-flow speed: twice the trip time, twice the period; a measured speed faster than
    free flow does not shorten it (the slower of the two)."""
    from sumo_scendiff.fill import seed as fs
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    sample, fringe = fs.inflow_sample(net, 0.0, 0, 100)
    free_speed = fs.route_metres(net, sample) / fs.trip_seconds(net, sample)   # m/s over the routes at free flow
    free = fs.write_inflow(str(tmp_path / "free.rou.xml"), net, 100, 0.0, 0, sample=sample, fringe=fringe)
    half = fs.write_inflow(str(tmp_path / "half.rou.xml"), net, 100, 0.0, 0, speed=free_speed / 2, sample=sample,
                           fringe=fringe)
    fast = fs.write_inflow(str(tmp_path / "fast.rou.xml"), net, 100, 0.0, 0, speed=free_speed * 2, sample=sample,
                           fringe=fringe)
    assert free["rate"]["trip_s_from"] == "free flow" and half["rate"]["trip_s_from"] == "measured"
    assert half["period_s"] == pytest.approx(2 * free["period_s"], rel=0.01)
    assert fast["period_s"] == free["period_s"]
    n = [(tmp_path / f"{k}.rou.xml").read_text().count("<trip ") for k in ("free", "half")]
    assert n[1] == pytest.approx(n[0] / 2, rel=0.05)


def test_probe_keeps_the_filled_number(filled):
    """The probe on a filled network (its saved state in SUMO, no inflow): vehicles that leave are
    replaced by the sample's trips, so the count stays near the filled one, and the speed it measures
    is that of a moving network with stops, below the limits."""
    from sumo_scendiff.fill.seed import inflow_sample, probe_speed
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    out, doc = filled
    net = Network.load(NET)
    sample, _ = inflow_sample(net, 0.0, 0)
    sim = start(SimConfig(net=NET, begin=doc["state_time"], extra=("--load-state", str(out / "state.xml.gz"))))
    try:
        n0 = sim.vehicle.getIDCount()
        probe = probe_speed(sim, sample, seconds=30.0, settle=30.0)
        # running, plus the replacements of the last step's arrivals, loaded for the next step
        assert abs(sim.simulation.getMinExpectedNumber() - n0) <= 1
    finally:
        close(sim)
    rec = probe.record
    assert n0 == doc["summary"]["vehicles"] and rec["settle_s"] == rec["seconds"] == 30.0
    assert 0.5 < rec["mean_speed_ms"] < 13.9 and rec["vehicles_mean"] >= 0.8 * n0
    assert rec["replaced"] == len(probe.departures) > 0       # the 3x3 grid has no fringe: they leave
    times = [t for t, _ in probe.departures]
    assert times == sorted(times) and doc["state_time"] < times[0] and times[-1] <= probe.until
    assert all(r in sample for _, r in probe.departures)


def test_no_overlap_and_no_duplicates(filled):
    _, doc = filled
    ids = [a["vehicle"] for a in doc["agents"] if a["vehicle"]]
    assert len(ids) == len(set(ids))
    b = _boxes(doc)
    polys = shapely.polygons(box_corners(*b.T))
    i, j = shapely.STRtree(polys).query(polys, predicate="intersects")
    pairs = [(p, q) for p, q in zip(i, j) if p < q and shapely.area(shapely.intersection(polys[p], polys[q])) > 1e-3]
    assert not pairs
    d = np.linalg.norm(b[:, None, :2] - b[None, :, :2], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() > 1.0
    # every vehicle in exactly one core: the one of the tile that kept it
    for a in doc["agents"]:
        cores = [t["index"] for t in doc["tiles"]
                 if t["core"][0] <= a["x"] < t["core"][2] and t["core"][1] <= a["y"] < t["core"][3]]
        assert cores == [a["tile"]]


def test_pins_across_tile_borders(tmp_path):
    """A bigger grid, where later tiles see their neighbours' vehicles: those are pinned, never
    kept twice, and a tile's own kept agents overlap none of them."""
    from sumo_scendiff.fill.plan import fill_network
    from sumo_scendiff.fill.tiles import tile_grid
    from sumo_scendiff.generation.generator import ScenarioGenerator
    from sumo_scendiff.map.network import Network
    net = Network.load(NET4)
    tiles = tile_grid(net, area=(0.0, 0.0, 300.0, 300.0))
    res = fill_network(net, ScenarioGenerator.load(), tiles, seed=0)
    assert sum(r.pins for r in res.records) > 0
    rows = res.accepted.rows
    polys = shapely.polygons(box_corners(*rows[:, :5].T))
    i, j = shapely.STRtree(polys).query(polys, predicate="intersects")
    assert not [(p, q) for p, q in zip(i, j)
                if p < q and shapely.area(shapely.intersection(polys[p], polys[q])) > 1e-3]


def test_same_seed_same_fill(filled, tmp_path):
    _, doc = filled
    again = _fill(tmp_path / "again", "-s", "3", "--workers", "1")
    for d in (doc, again):
        d.pop("timing_s")
    assert again == doc
    other = _fill(tmp_path / "other", "-s", "4")
    assert [a["x"] for a in other["agents"]] != [a["x"] for a in doc["agents"]]


def _without_run_facts(doc: dict) -> dict:
    """fill.json without what may differ between two runs of one fill: timings and the workers."""
    return {k: v for k, v in doc.items() if k not in ("timing_s", "workers")}


def test_two_workers_give_the_same_fill(filled, tmp_path):
    """--workers 2 (two spawned processes, each loading the model) writes the fill one process does,
    agents byte for byte, and records the workers it used."""
    _, doc = filled
    two = _fill(tmp_path / "two", "-s", "3", "--workers", "2")
    assert two["workers"]["count"] == 2 and doc["workers"]["count"] == 1
    assert json.dumps(two["agents"]) == json.dumps(doc["agents"])
    assert _without_run_facts(two) == _without_run_facts(doc)


def test_the_library_call_writes_the_clis_fill(filled, tmp_path):
    """fill.api.fill is the CLI without flags: the same request gives the same folder; bad input
    raises FillError and leaves nothing."""
    from sumo_scendiff.fill.api import FillError, fill
    _, doc = filled
    done = fill(NET, None, out=str(tmp_path / "lib"), seed=3, workers=1)
    assert done.folder == str(tmp_path / "lib") and done.summary == doc["summary"]
    assert _without_run_facts(done.doc) == _without_run_facts(doc)
    with pytest.raises(FillError, match="exists"):
        fill(NET, 10.0, out=done.folder)
    with pytest.raises(FillError, match="no car lane inside"):
        fill(NET, None, area=(5000, 5000, 5200, 5200), out=str(tmp_path / "none"), workers=1)
    assert sorted(os.listdir(tmp_path)) == ["lib"]


def test_tasks_depend_on_the_colour_alone():
    """A colour's model calls: TASKS_PER_COLOUR where it has the tiles, more only where a call would
    exceed TILES_PER_TASK tiles (their size depends on the colour alone); every tile once, in order."""
    from sumo_scendiff.fill.plan import TASKS_PER_COLOUR, TILES_PER_TASK, tasks_of
    for n in (1, 3, 8, 9, 20, 100, 1000):
        groups = tasks_of(list(range(n)))
        assert [t for g in groups for t in g] == list(range(n))
        assert max(map(len, groups)) <= TILES_PER_TASK
        # two workers both have work where there are two tiles; few calls, never one per tile
        assert min(n, 2) <= len(groups) <= max(TASKS_PER_COLOUR, math.ceil(n / TILES_PER_TASK) + 1)


def test_ray_workers_give_the_same_fill(filled, tmp_path):
    pytest.importorskip("ray")
    _, doc = filled
    ray = _fill(tmp_path / "ray", "-s", "3", "--workers", "2", "--ray-address", "local")
    assert ray["workers"]["engine"] == "ray" and ray["workers"]["count"] == 2
    assert _without_run_facts(ray) == _without_run_facts(doc)


@pytest.mark.parametrize("cfg", ["scenario.sumocfg", "start.sumocfg"])
def test_stock_sumo_runs_the_fill(filled, cfg, tmp_path):
    from sumo_scendiff.core.tools import sumo_binary
    out, doc = filled
    summary = tmp_path / "summary.xml"
    # from a copy elsewhere: the folder carries its inputs
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(out), str(copy)], check=True)
    run = subprocess.run([sumo_binary(), "-c", str(copy / cfg), "--end", f"{doc['begin'] + 10:g}",
                          "--summary-output", str(summary)], check=False, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert "Error" not in run.stderr
    steps = [line for line in summary.read_text().splitlines() if "<step " in line]
    first = steps[0]
    running, arrived = (int(first.split(f'{k}="')[1].split('"')[0]) for k in ("running", "arrived"))
    # the fill is on the road from the start; one seeded at the very end of an edge leaving the
    # network has arrived by the end of the first step
    assert running + arrived >= doc["summary"]["vehicles"] - 1
    assert all('collisions="0"' in s for s in steps[:4])


def test_start_routes_name_every_seeded_vehicle(filled):
    out, doc = filled
    text = (out / "start.rou.xml").read_text()
    for a in doc["agents"]:
        if a["vehicle"]:
            assert f'id="{a["vehicle"]}"' in text


def test_no_car_lane(tmp_path, capsys):
    net = netconvert('<node id="a" x="0" y="0"/><node id="b" x="200" y="0"/>',
                     '<edge id="ab" from="a" to="b" numLanes="1" allow="pedestrian"/>',
                     str(tmp_path / "walk.net.xml"))
    err = _fail(capsys, "-n", net, "-o", str(tmp_path / "o"))
    assert "walk.net.xml" in err and "passenger car" in err
    assert not os.path.exists(tmp_path / "o")


def test_area_without_road(tmp_path, capsys):
    err = _fail(capsys, "-n", NET, "--area", "5000,5000,5200,5200", "-o", str(tmp_path / "o"))
    assert "--area" in err and "no car lane" in err
    assert not os.listdir(tmp_path)


def test_existing_output_needs_force(filled, capsys):
    out, _ = filled
    err = _fail(capsys, "-n", NET, "-o", str(out))
    assert "-o" in err and "--force" in err


@pytest.mark.parametrize("bad", [["--density", "-1"], ["--area", "1,2,3"], ["--p-mask", "0"],
                                 ["--stride", "200"], ["--begin", "-5"]])
def test_bad_values(tmp_path, capsys, bad):
    _fail(capsys, "-n", NET, "-o", str(tmp_path / "o"), *bad)


def test_an_output_folder_that_cannot_be(tmp_path, capsys):
    """-o under a file, or where no folder can be made (/proc): one line naming -o, at once."""
    (tmp_path / "a.txt").write_text("mine")
    err = _fail(capsys, "-n", NET, "-o", str(tmp_path / "a.txt" / "out"))
    assert "-o" in err and "a.txt is a file, not a folder" in err
    assert (tmp_path / "a.txt").read_text() == "mine"
    if os.path.isdir("/proc/self"):
        assert "cannot be created" in _fail(capsys, "-n", NET, "-o", "/proc/scendiff-out")


@pytest.mark.parametrize("n", ["0", "-2"])
def test_workers_must_be_positive(tmp_path, capsys, n):
    err = _fail(capsys, "-n", NET, "-o", str(tmp_path / "o"), "--workers", n)
    assert "--workers" in err and not os.path.exists(tmp_path / "o")


def test_ray_address_without_ray(tmp_path, capsys, monkeypatch):
    """Without Ray, --ray-address stops in one line naming the flag, as the sweep's --engine ray."""
    monkeypatch.setitem(sys.modules, "ray", None)     # import ray raises ImportError
    err = _fail(capsys, "-n", NET, "-o", str(tmp_path / "o"), "--ray-address", "127.0.0.1:6379")
    assert "--ray-address" in err and "needs Ray" in err


def test_density_needs_the_condition(tmp_path, capsys):
    """A model without the density condition refuses --density in one line (an older checkpoint's
    layout: the shipped model with its global token cut back to p_mask's 10 inputs)."""
    from sumo_scendiff.generation.generator import DEFAULT_CHECKPOINT
    from sumo_scendiff.model import checkpoint as ckpt
    ck = ckpt.load(DEFAULT_CHECKPOINT, "scenario-diffusion")
    ck["diffusion_config"]["unet"]["global_dim"] = 10
    for key in ("denoiser.net.global_emb.weight", "denoiser.net.global_mlp.0.weight"):
        ck["diffusion"][key] = ck["diffusion"][key][:, :10].clone()
    old = str(tmp_path / "old.pt")
    ckpt.save(old, "scenario-diffusion", **{k: v for k, v in ck.items() if k not in ("format", "version", "kind")})
    err = _fail(capsys, "-n", NET, "-o", str(tmp_path / "o"), "--density", "25", "--checkpoint", old)
    assert "--density" in err and "density condition" in err and "--p-mask" in err


def test_the_fill_follows_the_density_asked(tmp_path):
    """With the shipped model's density condition the fill holds --density: each tile's core its
    count (the generator's count areas), within 10 % over the network."""
    low = _fill(tmp_path / "low", "--density", "8", net=NET4)
    high = _fill(tmp_path / "high", "--density", "40", net=NET4)
    assert low["density"]["applied"] and high["density"]["applied"]
    assert len(high["agents"]) > 2 * len(low["agents"])
    for doc, asked in ((low, 8.0), (high, 40.0)):
        assert abs(doc["summary"]["density_veh_per_km"] - asked) <= 0.1 * asked


def test_tile_counts_add_up_to_the_network_total():
    """Tiles expecting less than half a vehicle each would all round to 0: the counts are apportioned
    by largest remainder, so they add up to the rounded total, ties to the lower tile index; a tile
    without a target stays without one."""
    from sumo_scendiff.fill.plan import whole_counts
    kms = [0.1, 0.1, 0.1, 0.1, 0.2, 0.3]
    targets = [4.0, 4.0, 4.0, 4.0, None, 5.0]          # expected 0.4 each, none, 1.5
    got = whole_counts(targets, kms)
    counts = [None if d is None else round(d * km) for d, km in zip(got, kms)]
    # 0.4 x 4 + 1.5 = 3.1 -> 3: the floor gives the last tile 1; the largest remainders (its 0.5,
    # then the first tile's 0.4) the other 2
    assert counts == [1, 0, 0, 0, None, 2]
    assert whole_counts([None, None], [1.0, 1.0]) == [None, None]


def test_the_inflow_enters_at_a_fringe_that_can_take_it(tmp_path):
    """A crossing whose arms end in netconvert's turnarounds: each arm's edge into the crossing is a
    way in (the turnaround, an internal edge, leads onto it from its own reverse: not a way in). The
    inflow enters there while those four lanes can insert its rate, anywhere beyond that."""
    from sumo_scendiff.fill import seed as fs
    from sumo_scendiff.map.network import Network

    from .conftest import crossing
    net = Network.load(crossing(str(tmp_path / "turn.net.xml"), 1, turnarounds=True))
    assert fs.fringe_sources(net) == ["ec", "nc", "sc", "wc"]
    few, at_fringe = fs.inflow_sample(net, 0.0, 0, vehicles=4)
    assert at_fringe and few and all(r[0] in ("ec", "nc", "sc", "wc") for r in few)
    many, at_fringe = fs.inflow_sample(net, 0.0, 0, vehicles=10_000)
    assert not at_fringe and many
    doc = fs.write_inflow(str(tmp_path / "in.rou.xml"), net, 10_000, 0.0, 0)
    assert doc["from"].startswith("anywhere (the fringe's 4 edges cannot insert")


def test_a_stopped_fill_leaves_nothing(tmp_path):
    """SIGTERM in the middle of a fill: exit 130, one line, no folder and no partial one left."""
    import signal
    import time
    out = tmp_path / "stopped"
    proc = subprocess.Popen([sys.executable, "-m", "sumo_scendiff.fill", "-n", NET, "-o", str(out), "--workers", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 600
    while not any(".partial-" in p for p in os.listdir(tmp_path)) and proc.poll() is None \
            and time.monotonic() < deadline:
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 130, err[-400:]
    assert err.strip().splitlines()[-1] == f"python -m sumo_scendiff.fill: interrupted: nothing written to {out}"
    assert os.listdir(tmp_path) == []
