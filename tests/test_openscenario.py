"""Scenes that leave SUMO: OpenSCENARIO 1.2 + OpenDRIVE of a scene folder (real SUMO, netconvert and
libsumo; the ASAM schemas scenariogeneration ships, read here with xmlschema, the export's own check
being lxml's), read back, and OpenSCENARIO Init read as tokens."""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.cosim import CoSimulation
from sumo_scendiff.sim.export import ScenarioWriter
from sumo_scendiff.sim.rollout import rollout
from sumo_scendiff.sim.sumo import SimConfig, start
from sumo_scendiff.tokens.file import TokenFileError, load_tokens

ROLLOUT = 5.0
TOKEN = {"x": -60.0, "heading": 0.0}


def _cli(module: str, *args: str, cache: str, cwd: str | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "XDG_CACHE_HOME": cache}
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, env=env, cwd=cwd)


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("cache"))


@pytest.fixture(scope="module")
def folder(cross_net, cross_scene, tmp_path_factory) -> str:
    """A seeded scene folder (one user token, one agent SUMO refuses, one vehicle of the host
    simulation kept: ``host``, southbound 30 m north of the junction) with a 5 s rollout."""
    out = tmp_path_factory.mktemp("scenes")
    net = Network.load(cross_net)
    scene = cross_scene(net)
    cfg = SimConfig(net=cross_net)
    sim = start(cfg)
    try:
        sim.route.add("host_route", ["nc", "cs"])
        sim.vehicle.add("host", "host_route", departPos="170", departSpeed="5")
        sim.simulationStep()
        cosim = CoSimulation(sim, net, generator=None)
        existing = cosim.existing(scene.window)
        assert existing.token_ids() == ["host"]
        seeding = cosim.place(scene, [{**TOKEN, "y": float(scene.boxes[0, 1])}] + existing.tokens(),
                              ["user"] + existing.token_ids(), existing, seed=3, p_mask=0.5)
        sim.simulationStep()
        cosim.verify(seeding)
        writer = ScenarioWriter(str(out), "scene_000")
        writer.after_seeding(sim, seeding, net, cfg.options(), {"scene": "scene_000"})
        path = writer.finish(rollout(sim, seeding.agent_ids, ROLLOUT).as_dict() | {"seconds": ROLLOUT})
    finally:
        sim.close()
    return path


@pytest.fixture(scope="module")
def exported(folder, cache) -> str:
    res = _cli("sumo_scendiff.export", folder, "--format", "openscenario", cache=cache)
    assert res.returncode == 0, res.stderr
    return folder


def _scene(folder: str) -> dict:
    with open(os.path.join(folder, "scene.json")) as f:
        return json.load(f)


def _trajectories(root: ET.Element) -> dict[tuple[str, str], list[tuple[float, float, float, float]]]:
    """(entity, story) -> [(t, x, y, h)] of its FollowTrajectoryAction's polyline."""
    out = {}
    for story in root.iter("Story"):
        for group in story.iter("ManeuverGroup"):
            actor = group.find("Actors/EntityRef").get("entityRef")
            for vertex_list in group.iter("Polyline"):
                out[actor, story.get("name")] = [
                    (float(v.get("time")), *(float(v.find("Position/WorldPosition").get(k)) for k in "xyh"))
                    for v in vertex_list.findall("Vertex")]
    return out


def _init_poses(root: ET.Element) -> dict[str, tuple[float, float, float, float]]:
    out = {}
    for private in root.iter("Private"):
        wp = private.find(".//TeleportAction/Position/WorldPosition")
        speed = private.find(".//AbsoluteTargetSpeed")
        out[private.get("entityRef")] = (float(wp.get("x")), float(wp.get("y")), float(wp.get("h")),
                                         float(speed.get("value")))
    return out


def _angle(a: float, b: float) -> float:
    return abs(math.atan2(math.sin(a - b), math.cos(a - b)))


def test_files_validate_against_the_asam_schemas(exported):
    import xmlschema

    from sumo_scendiff.export.schema import openscenario_xsd
    for name in ("scenario.xosc", "scenario.xodr", "openscenario.json"):
        assert os.path.isfile(os.path.join(exported, name))
    assert not [n for n in os.listdir(exported) if ".partial" in n]
    xmlschema.XMLSchema(openscenario_xsd(2)).validate(os.path.join(exported, "scenario.xosc"))
    with open(os.path.join(exported, "openscenario.json")) as f:
        record = json.load(f)
    od = record["opendrive"]
    assert od["opendrive"] == "1.4" and od["offset"] == [0.0, 0.0]
    # the 1.7 schema is the only one shipped: recorded as a check of another revision
    assert od["schema"]["checked"] and not od["schema"]["same_revision"]
    assert record["xosc_schema"]["valid"] and record["played"] == "sumo"


def test_opendrive_is_in_the_network_coordinates(exported, cross_net):
    """A road's reference line starts at its SUMO edge (the side of its lanes): offset (0, 0)."""
    net = Network.load(cross_net)
    root = ET.parse(os.path.join(exported, "scenario.xodr")).getroot()
    checked = 0
    for road in root.findall("road"):
        sumo_id = road.find("userData[@code='sumoId']")
        if sumo_id is None or road.get("junction") != "-1":
            continue
        g = road.find("planView/geometry")
        lanes = [ln for ln in net.lanes if ln.edge == sumo_id.get("value")]
        start = min(lanes, key=lambda ln: math.dist(ln.shape[0], (float(g.get("x")), float(g.get("y")))))
        across = sum(ln.width for ln in lanes)
        assert math.dist(start.shape[0], (float(g.get("x")), float(g.get("y")))) <= across
        checked += 1
    assert checked >= 8


def test_round_trip_within_5_cm_and_10_mrad(exported):
    """Every exported vehicle where scene.json has it at t = 0 (Init) and at +1, +2 s (the
    generated story's polyline), its token in its properties; the refused one is not exported."""
    scene = _scene(exported)
    root = ET.parse(os.path.join(exported, "scenario.xosc")).getroot()
    init, paths = _init_poses(root), _trajectories(root)
    in_sumo = [a for a in scene["agents"] if a["vehicle"]]
    assert set(init) == {a["vehicle"] for a in in_sumo} | {"host"}
    assert len(in_sumo) < len(scene["agents"])          # the off-road agent: refused, not exported
    for a in in_sumo:
        x, y, h, v = init[a["vehicle"]]
        assert math.dist((x, y), (a["x"], a["y"])) <= 0.05 and _angle(h, a["heading"]) <= 0.01
        assert abs(v - a["speed"]) <= 0.01
        future = [p for p in a["poses"] if p["t"] > 0 and p["observed"]]
        assert bool(future) == ((a["vehicle"], "generated") in paths)   # none where the future is unknown
        path = {t: (px, py, ph) for t, px, py, ph in paths.get((a["vehicle"], "generated"), [])}
        for p in future:
            px, py, ph = path[p["t"]]
            assert math.dist((px, py), (p["x"], p["y"])) <= 0.05 and _angle(ph, p["heading"]) <= 0.01
    props = {o.get("name"): {p.get("name"): p.get("value") for p in o.iter("Property")}
             for o in root.iter("ScenarioObject")}
    tokened = [a for a in in_sumo if a["token"] is not None]
    assert tokened
    for a in tokened:
        assert json.loads(props[a["vehicle"]]["token"]) == scene["tokens"][a["token"]]
        assert int(props[a["vehicle"]]["token_index"]) == a["token"]


def test_a_kept_vehicle_is_exported_where_sumo_has_it(exported):
    """The host simulation's vehicle the scene kept: an entity with its token, at SUMO's pose (one
    step on from the token, taken before seeding; the window is the world frame here)."""
    scene = _scene(exported)
    root = ET.parse(os.path.join(exported, "scenario.xosc")).getroot()
    k, token = next((k, t) for k, t in enumerate(scene["tokens"]) if t["source"] == "host")
    props = {p.get("name"): p.get("value") for o in root.iter("ScenarioObject") if o.get("name") == "host"
             for p in o.iter("Property")}
    assert props["status"] == "kept" and int(props["token_index"]) == k and json.loads(props["token"]) == token
    x, y, h, v = _init_poses(root)["host"]
    assert abs(x - token["x"]) < 0.05 and 0 < token["y"] - y <= 0.5 * token["speed"] + 1.0
    assert _angle(h, token["heading"]) < 0.01
    assert ("host", "sumo") in _trajectories(root) and ("host", "generated") not in _trajectories(root)


def test_sumo_story_is_the_drive_at_the_step_length(exported):
    """The sumo story: SUMO's path from the folder's start, a vertex every step for the rollout."""
    root = ET.parse(os.path.join(exported, "scenario.xosc")).getroot()
    init = _init_poses(root)
    drives = {e: p for (e, s), p in _trajectories(root).items() if s == "sumo"}
    assert set(drives) == set(init)
    for name, path in drives.items():
        times = [t for t, *_ in path]
        assert times[0] == 0.0 and all(abs(b - a - 0.5) < 1e-6 for a, b in zip(times, times[1:]))
        assert times[-1] == ROLLOUT or len(times) < ROLLOUT / 0.5 + 1   # to the end, or until it left
        assert math.dist(path[0][1:3], init[name][:2]) < 0.5            # SUMO starts it where it stands


def test_export_refuses_to_replace_without_force(exported, cache):
    res = _cli("sumo_scendiff.export", exported, cache=cache)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "--force" in res.stderr


def test_exported_init_reads_back_as_world_tokens(exported, cross_net):
    spec = load_tokens(os.path.join(exported, "scenario.xosc"), net=Network.load(cross_net))
    agents = {(round(a["x"], 6), round(a["y"], 6)): a for a in spec.agents}
    assert spec.frame == "world" and len(agents) == len(_init_poses(ET.parse(
        os.path.join(exported, "scenario.xosc")).getroot()))
    for a in (a for a in _scene(exported)["agents"] if a["vehicle"]):
        t = agents[round(a["x"], 6), round(a["y"], 6)]
        assert all(abs(t[k] - a[k]) < 1e-6 for k in ("heading", "length", "width", "speed"))


def _example(folder: str, position, road: str = "../xodr/e6mini.xodr") -> str:
    """A scenario written with scenariogeneration's own API and ScenarioGenerator, as its
    trajectory example builds one (a white car, its reference point the rear axle: the box's
    centre 2 m ahead of it), placed at ``position`` (an xosc position)."""
    from scenariogeneration import ScenarioGenerator, xosc

    class Example(ScenarioGenerator):
        def __init__(self):
            super().__init__()
            self.open_scenario_version = 2

        def scenario(self, **kwargs):
            bb = xosc.BoundingBox(2, 5, 1.8, 2.0, 0, 0.9)
            fa = xosc.Axle(0.523598775598, 0.8, 1.68, 2.98, 0.4)
            ba = xosc.Axle(0.523598775598, 0.8, 1.68, 0, 0.4)
            white = xosc.Vehicle("car_white", xosc.VehicleCategory.car, bb, fa, ba, 69, 10, 10)
            entities = xosc.Entities()
            entities.add_scenario_object("Ego", white)
            init = xosc.Init()
            step = xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 1)
            init.add_init_action("Ego", xosc.AbsoluteSpeedAction("$EgoSpeed", step))
            init.add_init_action("Ego", xosc.TeleportAction(position))
            params = xosc.ParameterDeclarations()
            params.add_parameter(xosc.Parameter("$EgoSpeed", xosc.ParameterType.double, "8.5"))
            return xosc.Scenario("example", "Mandolin", params, entities, xosc.StoryBoard(init),
                                 xosc.RoadNetwork(road), xosc.Catalog(), osc_minor_version=2)

    files, _ = Example().generate(folder)
    return files[0]


def test_a_scenariogeneration_example_reads_as_tokens(cross_net, tmp_path):
    """A file the project did not write: the box centre 2 m ahead of the reference point, the
    speed a parameter; then the example as shipped (a lane position of its own road): one line."""
    from scenariogeneration import xosc
    net = Network.load(cross_net)
    east = next(ln for ln in net.lanes if ln.edge == "wc")
    y = float(east.shape[0][1])
    path = _example(str(tmp_path / "world"), xosc.WorldPosition(-80.0, y, 0, 0))
    spec = load_tokens(path, net=net)
    (a,) = spec.agents
    assert spec.frame == "world" and math.dist((a["x"], a["y"]), (-78.0, y)) < 1e-9
    assert (a["length"], a["width"], a["speed"], a["heading"]) == (5.0, 2.0, 8.5, 0.0)
    lane = _example(str(tmp_path / "lane"), xosc.LanePosition(25, 0, -3, 0))
    with pytest.raises(TokenFileError, match="LanePosition: its OpenDRIVE ../xodr/e6mini.xodr: not readable"):
        load_tokens(lane, net=net)
    off = _example(str(tmp_path / "off"), xosc.WorldPosition(-80.0, 60.0, 0, 0))
    with pytest.raises(TokenFileError, match=r"Ego.*off the network"):
        load_tokens(off, net=net)


def test_an_xosc_without_init_stops_run_in_one_line(cross_net, tmp_path, cache):
    bad = tmp_path / "no_init.xosc"
    bad.write_text('<OpenSCENARIO><FileHeader revMajor="1" revMinor="2"/><Entities/></OpenSCENARIO>')
    res = _cli("sumo_scendiff.run", "-n", cross_net, "--tokens", str(bad), "--scenes", "1", "--rollout", "0",
               "-o", str(tmp_path / "out"), cache=cache)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "no Storyboard Init" in res.stderr
    assert "Traceback" not in res.stderr and not os.path.exists(tmp_path / "out" / "scene_000")


def test_bad_folders_one_line_nothing_half_written(folder, tmp_path, cache):
    res = _cli("sumo_scendiff.export", str(tmp_path), cache=cache)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "no scene.json" in res.stderr
    broken = tmp_path / "broken"
    shutil.copytree(folder, broken, ignore=shutil.ignore_patterns("scenario.xo*", "openscenario.json"))
    net = next(n for n in os.listdir(broken) if ".net.xml" in n)
    (broken / net).write_text("<net><edge id='e' from='a' to='b'><lane id='e_0' shape='0,0'/></edge>")
    res = _cli("sumo_scendiff.export", str(broken), cache=str(tmp_path / "fresh_cache"))
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "netconvert" in res.stderr
    assert not [n for n in os.listdir(broken) if n.startswith(("scenario.xo", "openscenario")) or ".partial" in n]
    assert not [n for n in os.listdir(tmp_path / "fresh_cache" / "sumo-scendiff" / "opendrive")]


@pytest.mark.slow
def test_run_exports_every_scene(cross_net, tmp_path, cache):
    out = tmp_path / "run"
    res = _cli("sumo_scendiff.run", "-n", cross_net, "--center", "0,0", "--scenes", "1", "--rollout", "2",
               "-o", str(out), "--export", "openscenario", cache=cache)
    assert res.returncode == 0, res.stderr
    from sumo_scendiff.export.openscenario import validate_xosc
    validate_xosc(str(out / "scene_000" / "scenario.xosc"))
    with open(out / "scene_000" / "openscenario.json") as f:
        assert json.load(f)["vehicles"] == sum(a["vehicle"] is not None for a in _scene(str(out / "scene_000"))["agents"])


def test_two_workers_export_two_folders_alike(folder, exported, tmp_path, cache):
    """Local worker processes (core.pool) write what one process writes."""
    copies = [tmp_path / f"copy{k}" for k in range(2)]
    for c in copies:
        shutil.copytree(folder, c, ignore=shutil.ignore_patterns("scenario.xo*", "openscenario.json"))
    res = _cli("sumo_scendiff.export", *map(str, copies), "--workers", "2", cache=cache)
    assert res.returncode == 0, res.stderr
    with open(os.path.join(exported, "scenario.xosc")) as f:
        one = f.read()
    for c in copies:
        with open(c / "scenario.xosc") as f:
            assert f.read() == one


def _seeded_copies(folder: str, tmp_path, seeds) -> list[str]:
    """Copies of ``folder`` unexported, each with its own ``--seed`` (SUMO's drive from it differs)."""
    out = []
    for seed in seeds:
        copy = tmp_path / f"seed{seed}"
        shutil.copytree(folder, copy, ignore=shutil.ignore_patterns("scenario.xo*", "openscenario.json"))
        cfg = copy / "scenario.sumocfg"
        text = cfg.read_text()
        cfg.write_text(text.replace('<seed value="0"/>', f'<seed value="{seed}"/>'))
        assert f'<seed value="{seed}"/>' in cfg.read_text()
        out.append(str(copy))
    return out


def test_one_sumo_replays_the_folders_of_a_network_as_each_its_own(folder, tmp_path):
    """Folders of one network replayed in one SUMO, each state loaded into it, record what each
    records in a SUMO of its own, in any order and whatever seed (the generators as ``--seed`` sets
    them, no lane left simulated from the folder before), and that SUMO is kept for them."""
    from sumo_scendiff.export.openscenario import kept_vehicles
    from sumo_scendiff.export.replay import Replayer, replay
    folders = _seeded_copies(folder, tmp_path, (0, 7, 23))
    doc = _scene(folder)
    ids = [a["vehicle"] for a in doc["agents"] if a.get("vehicle")] + list(kept_vehicles(doc))
    own = {f: replay(os.path.join(f, "scenario.sumocfg"), ids, ROLLOUT) for f in folders}
    assert len({repr(r.paths) for r in own.values()}) == 3      # the seeds drive differently
    with Replayer() as r:
        for f in folders + folders[::-1]:
            assert r.replay(os.path.join(f, "scenario.sumocfg"), ids, ROLLOUT) == own[f], f
        assert r.key is not None and not r.untrusted


def test_exporting_many_folders_writes_what_one_at_a_time_writes(folder, exported, tmp_path, cache):
    """``python -m sumo_scendiff.export`` on three folders of one network (one SUMO) writes the files it
    writes for each alone (a SUMO each)."""
    many = _seeded_copies(folder, tmp_path / "many", (0, 7, 23))
    alone = _seeded_copies(folder, tmp_path / "alone", (0, 7, 23))
    res = _cli("sumo_scendiff.export", *many, cache=cache)
    assert res.returncode == 0, res.stderr
    for f in alone:
        res = _cli("sumo_scendiff.export", f, cache=cache)
        assert res.returncode == 0, res.stderr
    for a, b in zip(many, alone):
        for name in ("scenario.xosc", "scenario.xodr"):
            with open(os.path.join(a, name), "rb") as x, open(os.path.join(b, name), "rb") as y:
                assert x.read() == y.read(), (a, name)
    # again with --force: the files replaced, nothing left beside them (the OpenDRIVE is a link to the cache)
    res = _cli("sumo_scendiff.export", *many, "--force", cache=cache)
    assert res.returncode == 0, res.stderr
    assert not [p for f in many for p in os.listdir(f) if "partial" in p]


def test_a_lane_position_on_netconverts_opendrive_is_read(exported, cross_net, tmp_path):
    """LanePosition (road, lane -1, s, offset) on the exported scenario.xodr: the SUMO lane its road
    and lane stand for, s scaled to the lane's length, offset to the left (sumolib computes it here)."""
    import sumolib
    from scenariogeneration import xosc
    xodr = os.path.join(exported, "scenario.xodr")
    road = next(r for r in ET.parse(xodr).getroot().findall("road")
                if r.find("userData[@code='sumoId']") is not None and r.find("userData").get("value") == "wc")
    path = _example(str(tmp_path), xosc.LanePosition(40.0, 0.5, -1, road.get("id")), road=xodr)
    (a,) = load_tokens(path, net=Network.load(cross_net)).agents
    lane = sumolib.net.readNet(cross_net).getLane("wc_0")
    x, y = sumolib.geomhelper.positionAtShapeOffset(lane.getShape(), 40.0 * lane.getLength() / float(road.get("length")))
    assert math.dist((a["x"], a["y"]), (x + 2.0, y + 0.5)) < 0.05 and abs(a["heading"]) < 0.01
    bad = _example(str(tmp_path / "bad"), xosc.LanePosition(40.0, 0.0, -2, road.get("id")), road=xodr)
    with pytest.raises(TokenFileError, match="lane -2 of road .* is no lane of SUMO edge 'wc'"):
        load_tokens(bad, net=Network.load(cross_net))


@pytest.mark.slow
def test_the_fill_exports_its_init(cross_net, tmp_path, cache):
    """The fill's folder (fill.json, no rollout): Init only, every seeded vehicle where fill.json has it."""
    out = tmp_path / "fill"
    res = _cli("sumo_scendiff.fill", "-n", cross_net, "-o", str(out), "--export", "openscenario", cache=cache)
    assert res.returncode == 0, res.stderr
    with open(out / "fill.json") as f:
        agents = {a["vehicle"]: a for a in json.load(f)["agents"] if a["vehicle"]}
    root = ET.parse(out / "scenario.xosc").getroot()
    init = _init_poses(root)
    assert agents and set(init) == set(agents) and not _trajectories(root)
    for name, (x, y, h, v) in init.items():
        a = agents[name]
        assert math.dist((x, y), (a["x"], a["y"])) <= 0.05 and _angle(h, a["heading"]) <= 0.01


def test_the_picture_draws_the_file_beside_scene_png(exported, tmp_path):
    import cv2

    from sumo_scendiff.export.picture import draw
    out = str(tmp_path / "pic.png")
    draw(exported, out)
    img = cv2.imread(out)
    assert img is not None and img.shape[1] > img.shape[0] > 200   # two panels side by side


def test_the_picture_refuses_a_folder_not_exported_in_one_line(tmp_path):
    for args, words in (([], "required: folder, output"),
                        ([str(tmp_path), str(tmp_path / "p.png")], "no scene.png, scenario.xosc, scenario.xodr")):
        res = subprocess.run([sys.executable, "-m", "sumo_scendiff.export.picture", *args],
                             capture_output=True, text=True)
        assert res.returncode == 2 and words in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "p.png").exists()
