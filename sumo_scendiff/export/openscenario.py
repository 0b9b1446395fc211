"""A scene folder as ASAM OpenSCENARIO 1.2 (``scenario.xosc``, written with ``scenariogeneration``)
on netconvert's OpenDRIVE of its network (``scenario.xodr``), described in ``openscenario.json``.

    record = export_folder("out/scene_000")        # ExportError: one line naming the folder or file

One entity per vehicle SUMO holds at the start: the scene's agents (a refused one is in no
simulation: counted, not exported) and the simulation's own vehicles it kept (their pose SUMO's). Its reference point is the centre of its box on the ground (``scene.json``'s x, y), so
its BoundingBox centre is (0, 0, height / 2); Init teleports it to its world pose (the OpenDRIVE's
coordinates: the network's plus the recorded offset) at its speed. Two stories, one played
(``$Replay``, a global parameter players can override): ``generated``, the model's 0..+2 s future
as a timed polyline, and ``sumo``, the path SUMO drives from the folder's start for the rollout's
seconds at its step length (:mod:`.replay`); ``sumo`` by default where there is one. docs/openscenario.md.
"""
from __future__ import annotations

import datetime
import json
import os

import numpy as np

from ..core.files import read_json
from ..core.geometry import wrap_angle
from ..core.outputs import partial_path
from ..sim.scenario import ScenarioError, read_sumocfg
from .opendrive import ExportError, opendrive_for
from .replay import Replay, VehicleType, replay
from .schema import openscenario_xsd, schema_errors

FORMAT, VERSION = "sumo-scendiff-openscenario", 1
OSC_MINOR = 2
FILES = ("scenario.xodr", "scenario.xosc", "openscenario.json")
SUMO_STORY, GENERATED_STORY = "sumo", "generated"
# SUMO vClass -> OpenSCENARIO VehicleCategory (any other class: car)
CATEGORIES = {"delivery": "van", "truck": "truck", "trailer": "semitrailer", "bus": "bus", "coach": "bus",
              "motorcycle": "motorbike", "moped": "motorbike", "bicycle": "bicycle", "tram": "tram",
              "rail": "train", "rail_urban": "train", "rail_electric": "train", "rail_fast": "train"}
# SUMO has no axles: placed as docs/openscenario.md says (a fraction of the length either side of
# the centre, the track a little inside the box, a car's wheel); players need them only to draw wheels
AXLE_SHARE, TRACK_INSET, WHEEL, MAX_STEER = 0.3, 0.2, 0.7, 0.5


def read_folder(folder: str) -> tuple[dict, str]:
    """(the folder's scene.json or fill.json, its scenario.sumocfg)."""
    for name in ("scene.json", "fill.json"):
        path = os.path.join(folder, name)
        if os.path.isfile(path):
            break
    else:
        raise ExportError(f"{folder}: no scene.json (not a scene folder of run, a sweep or the fill)")
    doc = read_json(path, "JSON", ExportError)
    if not isinstance(doc.get("agents"), list):
        raise ExportError(f"{path}: no 'agents' list")
    config = os.path.join(folder, "scenario.sumocfg")
    if not os.path.isfile(config):
        raise ExportError(f"{folder}: no scenario.sumocfg")
    return doc, config


def rollout_seconds(folder: str, default: float) -> float:
    path = os.path.join(folder, "rollout.json")
    if os.path.isfile(path):
        with open(path) as f:
            return float(json.load(f).get("seconds", default))
    return default


def _unwrapped(yaws) -> list[float]:
    """Headings along a path without jumps of 2 pi (players interpolate between vertices)."""
    return [float(v) for v in np.unwrap(np.asarray(yaws, dtype=np.float64))]


def generated_path(agent: dict) -> list[tuple[float, float, float, float]]:
    """The model's t >= 0 poses (t, x, y, yaw) the scene gives (observed ones), t = 0 its pose."""
    poses = [p for p in agent.get("poses", []) if p["t"] >= 0 and p.get("observed", True)]
    if not poses or poses[0]["t"] != 0:
        poses = [{"t": 0.0, "x": agent["x"], "y": agent["y"], "heading": agent["heading"]}] + poses
    yaws = _unwrapped([agent["heading"]] + [p["heading"] for p in poses[1:]])
    return [(float(p["t"]), float(p["x"]), float(p["y"]), y) for p, y in zip(poses, yaws)]


def _vehicle(xosc, name: str, agent: dict, vt: VehicleType, tokens: list):
    length, width = float(agent["length"]), float(agent["width"])
    box = xosc.BoundingBox(width, length, vt.height, 0.0, 0.0, 0.5 * vt.height)
    front = xosc.Axle(MAX_STEER, WHEEL, width - TRACK_INSET, AXLE_SHARE * length, 0.5 * WHEEL)
    rear = xosc.Axle(0.0, WHEEL, width - TRACK_INSET, -AXLE_SHARE * length, 0.5 * WHEEL)
    category = getattr(xosc.VehicleCategory, CATEGORIES.get(vt.vclass, "car"))
    veh = xosc.Vehicle(name, category, box, front, rear, vt.max_speed, vt.accel, vt.decel)
    veh.add_property("sumo_id", name)
    veh.add_property("sumo_vclass", vt.vclass)
    veh.add_property("status", str(agent.get("status", "placed")))
    k = agent.get("token")
    if k is not None:   # the token as scene.json has it (in the scene's window frame), and its index there
        veh.add_property("token", json.dumps(tokens[k] if 0 <= k < len(tokens) else None, sort_keys=True))
        veh.add_property("token_index", str(k))
        veh.add_property("token_source", str(agent.get("token_source")))
    return veh


def _follow(xosc, name: str, story: str, path, offset) -> object:
    """A maneuver group making entity ``name`` follow ``path`` [(t, x, y, yaw)] on absolute time."""
    positions = [xosc.WorldPosition(x + offset[0], y + offset[1], 0.0, h) for _, x, y, h in path]
    traj = xosc.Trajectory(f"{name}_{story}", False)
    traj.add_shape(xosc.Polyline([t for t, *_ in path], positions))
    action = xosc.FollowTrajectoryAction(traj, xosc.FollowingMode.position, xosc.ReferenceContext.absolute, 1, 0)
    event = xosc.Event(f"{name}_{story}_follow", xosc.Priority.override)
    event.add_action(f"{name}_{story}_trajectory", action)
    event.add_trigger(xosc.ValueTrigger(f"{name}_{story}_start", 0, xosc.ConditionEdge.none,
                                        xosc.SimulationTimeCondition(0, xosc.Rule.greaterOrEqual)))
    man = xosc.Maneuver(f"{name}_{story}_maneuver")
    man.add_event(event)
    group = xosc.ManeuverGroup(f"{name}_{story}_group")
    group.add_actor(name)
    group.add_maneuver(man)
    return group


def _story(xosc, story: str, groups: list) -> object:
    cond = xosc.ParameterCondition("Replay", story, xosc.Rule.equalTo)
    act = xosc.Act(f"{story}_act", xosc.ValueTrigger(f"{story}_chosen", 0, xosc.ConditionEdge.none, cond))
    for g in groups:
        act.add_maneuver_group(g)
    s = xosc.Story(story)
    s.add_act(act)
    return s


def kept_vehicles(doc: dict) -> dict[str, int]:
    """The simulation's own vehicles the scene kept (run -r/-c, the co-simulation): SUMO id -> its
    token's index in scene.json's tokens. The model did not place them: SUMO has them where they stood."""
    return {t["source"]: k for k, t in enumerate(doc.get("tokens") or [])
            if t.get("source") not in (None, "user")}


def _kept_agents(doc: dict, rep: Replay) -> list[dict]:
    """Kept vehicles as agents: their pose, speed and box as SUMO has them at the start."""
    out = []
    for vid, k in kept_vehicles(doc).items():
        if vid in rep.types and rep.paths.get(vid) and rep.paths[vid][0][0] == 0.0:
            _, x, y, yaw, speed = rep.paths[vid][0]
            out.append({"vehicle": vid, "x": x, "y": y, "heading": yaw, "speed": speed, "status": "kept",
                        "length": rep.types[vid].length, "width": rep.types[vid].width,
                        "token": k, "token_source": vid})
    return out


def _network_name(doc: dict) -> str:
    """scene.json's network {"path", "name"}; fill.json's, its path."""
    net = doc.get("network") or "sumo"
    return net.get("name", "sumo") if isinstance(net, dict) else os.path.basename(str(net)).split(".net.xml")[0]


def _header_properties(xosc, doc: dict, info: dict, begin: float):
    props = xosc.Properties()
    for name, value in (("generator", "sumo-scendiff"), ("scene", doc.get("scene", "fill")),
                        ("sumo_network", _network_name(doc)),
                        ("sumo_begin_time", f"{begin:g}"), ("reference_point", "box centre on the ground"),
                        ("opendrive_offset_x", f"{info['offset'][0]:g}"), ("opendrive_offset_y", f"{info['offset'][1]:g}"),
                        ("sumo_net_offset_x", f"{info['net_offset'][0]:g}"), ("sumo_net_offset_y", f"{info['net_offset'][1]:g}"),
                        ("projection", info["projection"])):
        props.add_property(name, str(value))
    return props


def build_scenario(doc: dict, rep: Replay, info: dict, xodr_name: str = "scenario.xodr"):
    """(the scenariogeneration Scenario, what it holds) for a folder's document and SUMO's replay."""
    from scenariogeneration import xosc
    offset = info["offset"]
    agents = [a for a in doc["agents"] if a.get("vehicle") in rep.types]
    agents += [a for a in _kept_agents(doc, rep) if a["vehicle"] not in {b["vehicle"] for b in agents}]
    entities, init = xosc.Entities(), xosc.Init()
    stories = {GENERATED_STORY: [], SUMO_STORY: []}
    ends = [0.0]
    for a in agents:
        name = a["vehicle"]
        entities.add_scenario_object(name, _vehicle(xosc, name, a, rep.types[name], doc.get("tokens") or []))
        init.add_init_action(name, xosc.TeleportAction(
            xosc.WorldPosition(a["x"] + offset[0], a["y"] + offset[1], 0.0, float(a["heading"]))))
        init.add_init_action(name, xosc.AbsoluteSpeedAction(float(a["speed"]), xosc.TransitionDynamics(
            xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0)))
        gen = generated_path(a) if "poses" in a else []
        drove = rep.paths.get(name, [])
        drove = [(t, x, y, h) for (t, x, y, _, _), h in zip(drove, _unwrapped([p[3] for p in drove]))]
        for story, path in ((GENERATED_STORY, gen), (SUMO_STORY, drove)):
            if len(path) > 1:
                stories[story].append(_follow(xosc, name, story, path, offset))
                ends.append(path[-1][0])
    played = SUMO_STORY if stories[SUMO_STORY] else GENERATED_STORY if stories[GENERATED_STORY] else "none"
    params = xosc.ParameterDeclarations()
    params.add_parameter(xosc.Parameter("Replay", xosc.ParameterType.string, played))
    stop = xosc.ValueTrigger("end", 0, xosc.ConditionEdge.rising,
                             xosc.SimulationTimeCondition(max(ends) + rep.step, xosc.Rule.greaterThan), "stop")
    board = xosc.StoryBoard(init, stop)
    for story, groups in stories.items():
        if groups:
            board.add_story(_story(xosc, story, groups))
    when = datetime.datetime.fromtimestamp(0, datetime.timezone.utc)   # same scene, same file
    scenario = xosc.Scenario(f"{_network_name(doc)} {doc.get('scene', 'fill')}",
                             "sumo-scendiff", params, entities, board, xosc.RoadNetwork(xodr_name),
                             xosc.Catalog(), osc_minor_version=OSC_MINOR, creation_date=when,
                             header_properties=_header_properties(xosc, doc, info, rep.begin))
    held = {"vehicles": len(agents), "kept": sum(a.get("status") == "kept" for a in agents),
            "not_in_sumo": sum(1 for a in doc["agents"] if a.get("vehicle") not in rep.types),
            "stories": {k: len(v) for k, v in stories.items()}, "played": played}
    return scenario, held


def write_xml(scenario, path: str) -> None:
    """The scenario as indented XML (ElementTree's indent: a fill's thousands of vehicles take
    scenariogeneration's own minidom pretty-printer four times as long)."""
    import xml.etree.ElementTree as ET
    root = scenario.get_element()
    ET.indent(root, "    ")
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)


def validate_xosc(path: str) -> None:
    """Raises ExportError with the first schema error of ``path`` against OpenSCENARIO 1.2."""
    n, first = schema_errors(path, openscenario_xsd(OSC_MINOR))
    if n:
        raise ExportError(f"{path}: not valid against {os.path.basename(openscenario_xsd(OSC_MINOR))} "
                          f"({n} errors; {first[0]})")


def export_folder(folder: str, force: bool = False, seconds: float | None = None, replayer=None) -> dict:
    """Write scenario.xodr, scenario.xosc and openscenario.json into a finished scene folder, each
    under a .partial name until the xosc has validated. ``seconds``: SUMO's path to record (default:
    the folder's rollout; 0: none); ``replayer``: a :class:`~.replay.Replayer` to record it in (default:
    a SUMO of its own)."""
    import time
    t0 = time.perf_counter()
    doc, config = read_folder(folder)
    taken = [f for f in FILES if os.path.exists(os.path.join(folder, f))]
    if taken and not force:
        raise ExportError(f"{folder}: has {taken[0]} already (add --force to replace it)")
    try:
        net = read_sumocfg(config)["net"]
    except (ScenarioError, KeyError) as e:
        raise ExportError(f"{config}: {e if str(e) else 'names no network'}") from None
    od = opendrive_for(net)
    t1 = time.perf_counter()
    secs = rollout_seconds(folder, 0.0) if seconds is None else seconds
    ids = [a["vehicle"] for a in doc["agents"] if a.get("vehicle")] + list(kept_vehicles(doc))
    rep = replayer.replay(config, ids, secs) if replayer is not None else replay(config, ids, secs)
    t2 = time.perf_counter()
    scenario, held = build_scenario(doc, rep, od.info)
    final = {f: os.path.join(folder, f) for f in FILES}
    tmp = partial_path(final["scenario.xosc"])
    try:
        write_xml(scenario, tmp)
        validate_xosc(tmp)
        od.place(final["scenario.xodr"])
        os.replace(tmp, final["scenario.xosc"])
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    record = {"format": FORMAT, "version": VERSION, "xosc": "scenario.xosc", "xodr": "scenario.xodr",
              "openscenario": f"1.{OSC_MINOR}", "reference_point": "the box centre on the ground (scene.json's x, y)",
              "opendrive": od.info, **held,
              "trajectories": {GENERATED_STORY: "the model's poses at t = 0, +1, +2 s (scene.json)",
                               SUMO_STORY: {"source": "scenario.sumocfg replayed in libsumo", "seconds": secs,
                                            "step_length": rep.step, "sumo_begin": rep.begin}},
              "xosc_schema": {"schema": os.path.basename(openscenario_xsd(OSC_MINOR)), "valid": True},
              "timing_s": {"opendrive": round(t1 - t0, 3), "replay": round(t2 - t1, 3),
                           "write": round(time.perf_counter() - t2, 3)}}
    tmp = partial_path(final["openscenario.json"])
    with open(tmp, "w") as f:
        json.dump(record, f, indent=1)
    os.replace(tmp, final["openscenario.json"])
    return record
