"""Export of a seeded scene: the files, and replays in stock SUMO that put every agent back at the
pose scene.json records (real libsumo and the sumo binary)."""
from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest

from sumo_scendiff.core.tools import sumo_binary
from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.cosim import CoSimulation
from sumo_scendiff.sim.export import FILES, ScenarioWriter, pose_error
from sumo_scendiff.sim.rollout import rollout
from sumo_scendiff.sim.sumo import SimConfig, start


@pytest.fixture(scope="module", params=["libsumo", "traci"])
def exported(request, cross_net, cross_scene, tmp_path_factory):
    """The same seeding and export through libsumo (in-process) and traci (a sumo process)."""
    out = tmp_path_factory.mktemp("export")
    net = Network.load(cross_net)
    scene = cross_scene(net)
    scene.boxes[0, 1] += 0.6          # half a metre off the lane centre: must stay there
    scene.traj[0, :, 1] += 0.6
    cfg = SimConfig(net=cross_net, traci=request.param == "traci")
    sim = start(cfg)
    try:
        cosim = CoSimulation(sim, net, generator=None)
        seeding = cosim.place(scene, [{"x": -60.0, "y": float(scene.boxes[0, 1]), "heading": 0.0}],
                              ["user"], cosim.existing(scene.window), seed=3, p_mask=0.5)
        sim.simulationStep()
        cosim.verify(seeding)
        writer = ScenarioWriter(str(out), "scene_000")
        assert os.path.isdir(writer.tmp) and ".partial" in writer.tmp and not os.path.exists(out / "scene_000")
        writer.after_seeding(sim, seeding, net, cfg.options(), {"scene": "scene_000"})
        stats = rollout(sim, seeding.agent_ids, 5.0)
        folder = writer.finish(stats.as_dict())
    finally:
        sim.close()
    return folder, cross_net


def test_files_and_scene_json(exported):
    folder, _ = exported
    # the network travels in the folder, compressed, so the folder replays wherever it is copied
    assert sorted(os.listdir(folder)) == sorted(FILES + ("cross.net.xml.gz",))
    assert not [n for n in os.listdir(os.path.dirname(folder)) if ".partial" in n]
    doc = json.load(open(os.path.join(folder, "scene.json")))
    assert doc["format"] == "sumo-scendiff-scenario" and doc["version"] == 1
    assert doc["counts"] == {"generated": 5, "placed": 4, "misplaced": 0, "refused": 1, "existing": 0, "dropped": 0}
    agents = doc["agents"]
    assert [a["status"] for a in agents] == ["placed"] * 4 + ["refused"]
    assert agents[0]["token"] == 0 and agents[0]["token_source"] == "user"
    assert [a["token"] for a in agents[1:]] == [None] * 4
    assert agents[2]["heading"] == pytest.approx(np.pi / 2)
    # 1.95 m drawn, 1.8 m in SUMO: the width the network's junctions were built for (Seeder.width_cap)
    assert agents[2]["width"] == pytest.approx(1.95) and agents[2]["sumo_width"] == 1.8
    assert [a.get("sumo_width") for a in agents[:2]] == [None, None]
    assert len(agents[0]["poses"]) == 5 and agents[0]["y"] == pytest.approx(-1.6 + 0.6, abs=0.01)
    # agent 3 stands inside the junction: it departs on its internal edge, as exactly as the others
    assert [a["replay_exact"] for a in agents[:4]] == [True] * 4
    stats = json.load(open(os.path.join(folder, "rollout.json")))
    assert stats["agents"] == 4 and stats["seconds"] == 5.0 and stats["collisions"] == 0


def _check_poses(sim, doc, only_exact=False, heading=True):
    checked = 0
    for a in doc["agents"]:
        if a["status"] != "placed" or (only_exact and not a["replay_exact"]):
            continue
        dist, dyaw = pose_error(sim, a["vehicle"], a)
        assert dist < 0.5, (a["vehicle"], dist)
        if heading:
            assert dyaw < 0.1, (a["vehicle"], dyaw)
        checked += 1
    return checked


def test_sumocfg_replays_every_agent_at_its_pose(exported):
    import libsumo
    folder, _ = exported
    doc = json.load(open(os.path.join(folder, "scene.json")))
    libsumo.start([sumo_binary(), "-c", os.path.join(folder, "scenario.sumocfg"), "--no-warnings", "true"])
    try:
        assert _check_poses(libsumo, doc) == 4
    finally:
        libsumo.close()


def test_stock_sumo_runs_the_scenario(exported):
    folder, _ = exported
    res = subprocess.run([sumo_binary(), "-c", "scenario.sumocfg", "--end", "20"], cwd=folder,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "Error" not in res.stderr


def test_a_copied_folder_replays_in_stock_sumo(exported, tmp_path):
    """Self-contained: the folder copied elsewhere (the original network gone from its path) still
    runs, every input named relative to the folder."""
    import shutil
    folder, _ = exported
    copy = tmp_path / "elsewhere" / "scene"
    shutil.copytree(folder, copy)
    cfg = (copy / "scenario.sumocfg").read_text()
    assert "/" not in cfg.split('net-file value="')[1].split('"')[0]
    res = subprocess.run([sumo_binary(), "-c", "scenario.sumocfg", "--end", "10"], cwd=copy,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


def test_route_file_replays_every_agent(exported):
    """The plain route file, without the state: the agents on lanes depart at their pose, the one
    inside the junction on its internal lane at the position the state has it (its heading is then
    the lane's, which a state keeps as the scene drew it)."""
    import libsumo
    folder, net = exported
    doc = json.load(open(os.path.join(folder, "scene.json")))
    inside = doc["agents"][3]["vehicle"]
    libsumo.start([sumo_binary(), "-c", os.path.join(folder, "scenario.sumocfg"), "--no-warnings", "true"])
    try:
        state = libsumo.vehicle.getLaneID(inside), libsumo.vehicle.getLanePosition(inside)
    finally:
        libsumo.close()
    assert state[0].startswith(":")
    libsumo.start([sumo_binary(), "-n", net, "-r", os.path.join(folder, "scenario.rou.xml"),
                   "--lateral-resolution", "0.8", "--no-step-log", "true", "--no-warnings", "true"])
    try:
        libsumo.simulationStep()   # departures at t = 0
        lane_agents = dict(doc, agents=[a for a in doc["agents"] if a["vehicle"] != inside])
        assert _check_poses(libsumo, lane_agents, only_exact=True) == 3
        assert libsumo.vehicle.getLaneID(inside) == state[0]
        assert libsumo.vehicle.getLanePosition(inside) == pytest.approx(state[1], abs=0.05)
    finally:
        libsumo.close()


def test_writer_never_replaces_a_finished_scene(exported, tmp_path):
    folder, _ = exported
    with pytest.raises(FileExistsError, match="exists"):
        ScenarioWriter(os.path.dirname(folder), os.path.basename(folder))


def test_departures_are_fitted_to_their_box_centres(cross_net, tmp_path):
    """A departure whose box centre SUMO inserts 1 m behind and 0.3 m beside its pose is moved along
    and across its lane until it is there; one already there, and one without insertionChecks="none"
    (not an exact departure), are left alone."""
    import libsumo

    from sumo_scendiff.core.geometry import sumo_to_pose
    from sumo_scendiff.sim.export import fit_departures, write_sumocfg
    shape = _lane_shape(cross_net, "wc_0")
    y0 = shape[0][1]
    # a 5 m car whose front is at 101 m along wc (x = -200 + 101): its centre at x = -101.5
    rows = [("off", 101.0, 0.0, (-100.5, y0 + 0.3)), ("there", 60.0, 0.0, (-142.5, y0)),
            ("loose", 30.0, 0.0, (-160.0, y0))]
    veh = "".join(f'<vehicle id="{v}" depart="0" departLane="0" departPos="{p}" departPosLat="{lat}" '
                  f'departSpeed="0"{"" if v == "loose" else " insertionChecks=" + chr(34) + "none" + chr(34)}>'
                  '<route edges="wc ce"/></vehicle>' for v, p, lat, _ in rows)
    (tmp_path / "start.rou.xml").write_text(f'<routes><vType id="DEFAULT_VEHTYPE" length="5"/>{veh}</routes>')
    write_sumocfg(str(tmp_path / "start.sumocfg"), {"net-file": cross_net}, None,
                  routes=[str(tmp_path / "start.rou.xml")])
    poses = {v: xy for v, _, _, xy in rows}
    assert fit_departures(str(tmp_path / "start.sumocfg"), str(tmp_path / "start.rou.xml"), poses) == 1
    libsumo.start(["sumo", "-c", str(tmp_path / "start.sumocfg"), "--no-step-log", "--lateral-resolution", "0.8"])
    try:
        libsumo.simulationStep()
        for v, _, _, (x, y) in rows[:2]:
            fx, fy = libsumo.vehicle.getPosition(v)
            cx, cy, _ = sumo_to_pose(fx, fy, libsumo.vehicle.getAngle(v), libsumo.vehicle.getLength(v))
            assert abs(cx - x) < 0.15 and abs(cy - y) < 0.15, (v, cx, cy, x, y)
    finally:
        libsumo.close()
    assert 'id="loose" depart="0" departLane="0" departPos="30.0"' in (tmp_path / "start.rou.xml").read_text()


def _lane_shape(net_path: str, lane: str):
    from sumo_scendiff.map.network import Network
    return Network.load(net_path).sumo_net.getLane(lane).getShape()
