"""Honest records: every generated agent is placed, misplaced, refused, existing or dropped (with the reason);
the counts add up in scene.json, rollout.json and run.json; a replay of the exported folder in stock
SUMO finds every `placed` agent at its pose; a token of the user's gives a vehicle or a warning.
The shipped model, real libsumo and the `run` CLI, on a tiny crossing (small scale)."""
from __future__ import annotations

import json
import math

import pytest

from sumo_scendiff.core.tools import sumo_binary
from sumo_scendiff.sim.seeding import POS_TOLERANCE, STATUSES, YAW_TOLERANCE

from .test_run import _run, demand  # noqa: F401  (the CLI called in-process; cross_net's demand)

pytestmark = pytest.mark.slow   # real runs of the CLI: the fast tier is -m "not slow"


def _check_counts(doc: dict, roll: dict) -> None:
    counts = {s: 0 for s in STATUSES}
    for a in doc["agents"]:
        counts[a["status"]] += 1
        # a vehicle exactly for those SUMO has; a reason (or the error) for every one not placed
        assert (a["vehicle"] is None) == (a["status"] in ("refused", "existing", "dropped")), a
        if a["status"] == "misplaced":
            assert a["position_error"] > 0
        elif a["status"] != "placed":
            assert a["reason"], a
        if a["token"] is not None and a["token_source"] != "user":   # the model's copy of a kept vehicle
            assert a["status"] == "existing" and f"vehicle {a['token_source']!r} was already there and is kept" in a["reason"]
    assert {k: doc["counts"][k] for k in ("generated", *STATUSES)} == {"generated": len(doc["agents"]), **counts}
    assert {k: roll[k] for k in doc["counts"]} == doc["counts"]
    # the agents dropped for a vehicle already there: among the dropped, the model's copies not among them
    assert roll["dropped_on_existing"] == doc["dropped_on_existing"] <= counts["dropped"]


def _replay_finds_placed(folder, doc: dict) -> int:
    """Stock SUMO loads the folder's configuration; at its first instant every placed agent's front
    bumper stands where its box (centre, heading, length) puts it (DESIGN.md), within the seeder's
    tolerance, and no vehicle of the seeder's is there that no record names (a misplaced one may not
    be: SUMO saves a vehicle it holds on no lane for its next insertion)."""
    import libsumo
    libsumo.start([sumo_binary(), "-c", str(folder / "scenario.sumocfg"), "--no-warnings", "true"])
    try:
        present = set(libsumo.vehicle.getIDList())
        named = {a["vehicle"] for a in doc["agents"] if a["vehicle"]}
        assert {v for v in present if v.startswith("sd.")} <= named
        found = 0
        for a in [a for a in doc["agents"] if a["status"] == "placed"]:
            x, y = libsumo.vehicle.getPosition(a["vehicle"])
            h = a["heading"]
            fx, fy = a["x"] + 0.5 * a["length"] * math.cos(h), a["y"] + 0.5 * a["length"] * math.sin(h)
            yaw = math.radians(90.0 - libsumo.vehicle.getAngle(a["vehicle"]))
            assert math.hypot(x - fx, y - fy) <= POS_TOLERANCE, a["vehicle"]
            assert abs(math.remainder(yaw - h, 2 * math.pi)) <= YAW_TOLERANCE, a["vehicle"]
            found += 1
        return found
    finally:
        libsumo.close()


def test_records_add_up_and_a_replay_finds_every_placed_agent(cross_net, demand, tmp_path, capsys):
    out = tmp_path / "out"
    code, stdout, err = _run(["-n", cross_net, "-r", demand, "--begin", "15", "--center", "0,0",
                              "--scenes", "2", "--rollout", "2", "-s", "3", "--steps", "8", "--p-mask", "1", "--density", "40",
                              "-o", str(out)], capsys)
    assert code == 0, err
    summary = json.load(open(out / "run.json"))
    total = {s: 0 for s in ("generated", *STATUSES)}
    for row in summary["scenes"]:
        folder = out / row["scene"]
        doc = json.load(open(folder / "scene.json"))
        _check_counts(doc, json.load(open(folder / "rollout.json")))
        assert {k: row[k] for k in doc["counts"]} == doc["counts"]
        assert _replay_finds_placed(folder, doc) == doc["counts"]["placed"]
        total = {k: total[k] + doc["counts"][k] for k in total}
    assert total["generated"] == sum(total[s] for s in STATUSES) and total["placed"] > 0
    assert (f"of {total['generated']} generated agents: placed {total['placed']} " in stdout
            and f"refused by SUMO {total['refused']}, dropped {total['dropped']}" in stdout)


def test_a_cosimulation_records_agents_dropped_beside_the_hosts_vehicles(cross_net, cross_scene):
    """CoSimulation.place: the model's copy of a host's vehicle (drawn for its token) is ``existing``:
    the host's vehicle kept, the copy not added, not a failure; an agent on a host's vehicle is dropped
    with the vehicle named; a user's token whose agent that was is lost with that reason, and verify
    warns of it; the counts and scene.json's records add up."""
    import numpy as np

    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.cosim import CoSimulation, Existing
    from sumo_scendiff.sim.export import _dropped_before, scene_document
    from sumo_scendiff.sim.sumo import SimConfig, start
    net = Network.load(cross_net)
    scene = cross_scene(net)
    ex = Existing(["host0", "host1"], np.array([scene.boxes[0], scene.boxes[2] + [1.0, 0, 0, 0, 0]], np.float64),
                  np.zeros(2), np.array([True, True]))
    user = [{"x": float(scene.boxes[2, 0]), "y": float(scene.boxes[2, 1]), "heading": float(scene.boxes[2, 2])}]
    sim = start(SimConfig(net=cross_net))
    try:
        cosim = CoSimulation(sim, net, generator=None)
        seeding = cosim.place(scene, user + ex.tokens(), ["user"] + ex.token_ids(), ex)
        sim.simulationStep()
        with pytest.warns(UserWarning, match="token 0: no vehicle: its vehicle was dropped: its box overlaps"):
            cosim.verify(seeding)
        doc = scene_document(seeding, net, sim, {})
    finally:
        sim.close()
    # scene.json says each once: the copy is existing, the agent on host1 dropped on an existing vehicle
    assert (doc["counts"]["existing"], doc["counts"]["dropped"], doc["dropped_on_existing"]) == (1, 1, 1)
    assert seeding.before_reason == ["vehicle 'host0' was already there and is kept; the model's copy of it is not added",
                                     "its box overlaps vehicle 'host1', already there"]
    assert seeding.lost_tokens() == {0: "its vehicle was dropped: its box overlaps vehicle 'host1', already there"}
    assert seeding.counts() == {"generated": 5, "placed": 2, "misplaced": 0, "refused": 1, "existing": 1, "dropped": 1}
    records = _dropped_before(seeding)
    assert [(a["status"], a["token_source"]) for a in records] == [("existing", "host0"), ("dropped", "user")]


TOKENS = {"frame": "world", "agents": [
    # a truck 0.77 m left of the eastbound lane's centre line (y = -1.6): on its lane
    {"x": -30.0, "y": -0.83, "heading": 0.0, "length": 11.0, "width": 2.5, "speed": 8.0},
    # in a corner block, 20 m from every road: no vehicle can stand there
    {"x": 30.0, "y": 30.0, "speed": 5.0},
]}


def test_every_token_gives_a_vehicle_or_a_warning(cross_net, tmp_path, capsys):
    tok = tmp_path / "tokens.json"
    tok.write_text(json.dumps(TOKENS))
    out = tmp_path / "out"
    code, _, err = _run(["-n", cross_net, "--center", "0,0", "--tokens", str(tok), "--scenes", "1",
                         "--rollout", "0", "--steps", "8", "-o", str(out)], capsys)
    assert code == 0, err
    doc = json.load(open(out / "scene_000" / "scene.json"))
    truck = [a for a in doc["agents"] if a["token"] == 0]
    assert len(truck) == 1 and truck[0]["status"] == "placed" and truck[0]["vehicle"]
    assert abs(truck[0]["y"] + 1.6) < 0.1 and abs(truck[0]["heading"]) < 0.05    # on the lane
    assert "lost" not in doc["tokens"][0] and "token 0" not in err
    assert doc["tokens"][1]["lost"]
    lines = [ln for ln in err.splitlines() if "token 1: no vehicle:" in ln]
    assert len(lines) == 1 and str(tok) in lines[0] and "scene_000" in lines[0]
    assert json.load(open(out / "scene_000" / "rollout.json"))["user_tokens_lost"] == {"1": doc["tokens"][1]["lost"]}
