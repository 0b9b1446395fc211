"""Export of one seeded scene: the files of ``<out>/<scene>/`` (documented in the README).

    folder = ScenarioWriter(out_dir, "scene_000")        # writes into scene_000.partial-<pid>/
    folder.after_seeding(sim, seeding, net, sim_cfg, info)   # scene.json, routes, sumocfg, state, png
    folder.finish(stats)                                 # rollout.json, then rename to scene_000/

A scene folder only appears under its final name once every file is written; an interrupted run
leaves ``*.partial-<pid>`` folders, which are never mistaken for results. The name is the writing
process's own, so a folder in progress is never removed by another process (the owner of the output
directory, :mod:`~sumo_scendiff.core.outputs`, removes those of processes that died).
"""
from __future__ import annotations

import json
import math
import os
import shutil
from xml.sax.saxutils import quoteattr

import numpy as np

from ..core.geometry import sumo_to_pose, wrap_angle
from ..core.files import write_png
from ..core.outputs import partial_path, publish
from ..map.picture import draw_scene
from ..tokens.features import is_pinnable
from .additional import output_folders
from .bundle import bundle
from .fleet import DRAWN_KEY, PARENT_PARAM
from .seed_report import before_status
from .state import save_state
from .stops import stops_xml

FORMAT, VERSION = "sumo-scendiff-scenario", 1
FILES = ("scene.json", "scenario.rou.xml", "scenario.sumocfg", "state.xml.gz", "rollout.json", "scene.png")


def _agents(seeding, sim) -> list[dict]:
    """Per seeded agent: the generated pose in world coordinates and what became of it."""
    scene, rep = seeding.scene, seeding.report
    score = scene.meta.get("score", [None] * len(scene))
    stood = scene.meta.get("stood_at_red") or [False] * len(scene)
    fleet = scene.meta.get(DRAWN_KEY, {})
    out = []
    for i, a in enumerate(scene.world_agents()):
        vid = rep.ids.get(i)
        status, why = rep.status(i)
        tok = seeding.token_of[i]
        a.update({"vehicle": vid, "status": status, "score": None if score[i] is None else float(score[i]),
                  "token": tok, "token_source": None if tok is None else seeding.token_source[tok]})
        if status == "misplaced":
            a["position_error"] = why
        elif why is not None:
            a["reason"] = why
        if i in rep.pulled_back:   # its nose was over the stop line (Seeder.fit_lane_ends)
            a["pulled_back_m"] = round(rep.pulled_back[i], 3)
        if i in rep.to_stop_line:  # waiting inside a junction on red: moved to its stop line (Seeder.fit_red_junctions)
            a["to_stop_line_m"] = round(rep.to_stop_line[i], 3)
        if stood[i]:               # in a red light's queue, given standing (generation/red_queues.py)
            a["stood_at_red"] = True
        if i in fleet:             # seeded as one of the scenario's vTypes (sim/fleet.py)
            a.update(_vtype_record(sim, vid, fleet[i]))
        if i in rep.narrowed:      # wider than the network's junctions assume (Seeder.width_cap)
            a["sumo_width"] = rep.narrowed[i][1]
        out.append(a)
    return out + _dropped_before(seeding)


def _dropped_before(seeding) -> list[dict]:
    """The generated agents never handed to the seeder (on a vehicle already there), after the others:
    ``existing`` where the agent is the model's copy of that vehicle, else ``dropped``."""
    before = seeding.before
    if before is None or not len(before):
        return []
    score = before.meta.get("score", [None] * len(before))
    return [{**a, "vehicle": None, "status": before_status(tok, seeding.token_source), "reason": why,
             "score": None if score[i] is None else float(score[i]),
             "token": tok, "token_source": None if tok is None else seeding.token_source[tok]}
            for i, (a, why, tok) in enumerate(zip(before.world_agents(), seeding.before_reason, seeding.before_token))]


def _tokens(seeding, pin: bool) -> list[dict]:
    """The tokens given to the model; a user's that no vehicle realises says why (``lost``)."""
    lost = seeding.lost_tokens()
    return [{**t, "source": s, "pinned": pin and is_pinnable(t), **({"lost": lost[k]} if k in lost else {})}
            for k, (t, s) in enumerate(zip(seeding.tokens, seeding.token_source))]


def _vtype_record(sim, vid: str | None, drawn: tuple) -> dict:
    """The scenario's vType an agent was seeded as, SUMO's type id of its vehicle (a copy of it
    that may differ by minGap) and the box the model drew (its centre is the vehicle's)."""
    try:
        sumo_type = sim.vehicle.getTypeID(vid) if vid else None
    except Exception:   # not in the simulation (SUMO did not take it)
        sumo_type = None
    return {"vtype": drawn[0], "sumo_type": sumo_type,
            "drawn_length": round(drawn[1], 3), "drawn_width": round(drawn[2], 3)}


def scene_document(seeding, net, sim, info: dict) -> dict:
    w = seeding.scene.window
    pin = bool(info.get("model", {}).get("pin_tokens", False))  # held in the latent (pinning.py)
    return {"format": FORMAT, "version": VERSION, **info,
            "network": {"path": os.path.abspath(net.path), "name": net.name},
            "window": {"cx": w.cx, "cy": w.cy, "yaw": w.yaw, "size": w.size},
            "time": float(sim.simulation.getTime()), "seed": seeding.seed, "p_mask": seeding.p_mask,
            "tokens": _tokens(seeding, pin),
            # of ``dropped``: the agents whose box lay on or too close ahead of a vehicle already there
            # (the model's copies of those vehicles are ``existing``, counted apart)
            "dropped_on_existing": seeding.dropped,
            # the traffic lights the scene was generated with (tls id -> SUMO state string)
            "signals": seeding.scene.meta.get("signals", {}),
            "counts": seeding.counts(),       # generated = placed + misplaced + refused + existing + dropped
            "agents": _agents(seeding, sim)}


def declared_vtypes(paths) -> dict:
    """vType id -> its element in ``paths`` (route or additional files, read as SUMO reads them), for
    the definitions TraCI cannot read back: the car-following and lane-changing models and their
    parameters."""
    import copy

    from ..core.sumo_xml import elements
    return {el.get("id"): copy.deepcopy(el) for _, el in elements([p for p in paths if os.path.isfile(p)], ("vType",))
            if el.get("id")}


def loaded_files(sim) -> list[str]:
    """The route and additional files the running SUMO loaded."""
    out = []
    for option in ("route-files", "additional-files"):
        try:
            out += sim.simulation.getOption(option).replace(",", " ").split()
        except Exception:   # a SUMO without getOption
            pass
    return out


def _vtype_xml(sim, tid: str, declared: dict) -> str:
    """A seeded vehicle's own vType: where it copies one of the scenario's (sim/fleet.py), that
    definition under the copy's id and with its fitted minGap; else its box and the Krauss
    parameters it drives with."""
    import copy
    import xml.etree.ElementTree as ET
    vt = sim.vehicletype
    parent = declared.get(vt.getParameter(tid, PARENT_PARAM))
    if parent is not None:
        el = copy.deepcopy(parent)
        el.attrib.pop("probability", None)    # a member of a vTypeDistribution stands alone here
        el.set("id", tid)
        el.set("minGap", f"{vt.getMinGap(tid):.3f}")
        pid = vt.getParameter(tid, PARENT_PARAM)
        for name, get in (("length", vt.getLength), ("width", vt.getWidth)):
            if abs(get(tid) - get(pid)) > 1e-6:      # a user token's size (Seeder.fit_type)
                el.set(name, f"{get(tid):.3f}")
        el.tail = None
        return "    " + ET.tostring(el, encoding="unicode").strip()
    color = ",".join(str(c) for c in vt.getColor(tid))
    return (f'    <vType id={quoteattr(tid)} vClass="{vt.getVehicleClass(tid)}" length="{vt.getLength(tid):.3f}" '
            f'width="{vt.getWidth(tid):.3f}" minGap="{vt.getMinGap(tid):.3f}" accel="{vt.getAccel(tid):g}" '
            f'decel="{vt.getDecel(tid):g}" emergencyDecel="{vt.getEmergencyDecel(tid):g}" '
            f'sigma="{vt.getImperfection(tid):g}" tau="{vt.getTau(tid):g}" maxSpeed="{vt.getMaxSpeed(tid):g}" '
            f'speedFactor="normc({vt.getSpeedFactor(tid):g},{vt.getSpeedDeviation(tid):g},0.2,2)" '
            f'emissionClass={quoteattr(vt.getEmissionClass(tid))} color="{color}"/>')


def _vehicle_xml(sim, vid: str, net, declared: dict) -> tuple[str, str, str, bool]:
    """(vType, route, vehicle) XML for a present vehicle departing where it stands now, and
    whether that is exact. A vehicle inside a junction departs on its internal edge (SUMO accepts a
    route that starts with one, and finds the internal lanes between it and the next normal edge);
    only a vehicle SUMO reports on no lane, or whose route ends there, starts at the edge it is
    entering, at its start and with SUMO's insertion checks."""
    tid = sim.vehicle.getTypeID(vid)
    vt = sim.vehicletype
    # so that the start drives as the state does
    vtype = _vtype_xml(sim, tid, declared)
    edges = list(sim.vehicle.getRoute(vid))[sim.vehicle.getRouteIndex(vid):]
    lane = sim.vehicle.getLaneID(vid)
    exact = bool(lane) and (not lane.startswith(":") or len(edges) > 1)
    parked = None if lane else _parked_lane(sim, vid, edges)
    if parked:
        # SUMO gives a parked vehicle no lane; it departs standing where it parks, on its stop's lane
        # (its route from the stop's edge on), and parks again in the step after its departure
        pos, lane_index, lat = sim.vehicle.getLanePosition(vid), int(parked.rpartition("_")[2]), 0.0
    elif exact:
        pos, lane_index = sim.vehicle.getLanePosition(vid), sim.vehicle.getLaneIndex(vid)
        lat = sim.vehicle.getLateralLanePosition(vid)
        if lane.startswith(":"):   # the route index still points at the edge before the junction
            edges = [sim.lane.getEdgeID(lane)] + edges[1:]
    elif len(edges) > 1:
        edges = edges[1:]
        nxt = net.sumo_net.getEdge(edges[0])
        pos, lane_index, lat = min(vt.getLength(tid), nxt.getLength() - 0.1), "best", 0.0
    else:
        first = net.sumo_net.getEdge(edges[0])
        pos, lane_index, lat = first.getLength() - 0.1, "best", 0.0
    route = f'    <route id={quoteattr(vid + "_replay")} edges="{" ".join(edges)}"/>'
    stops = stops_xml(sim, vid)
    veh = (f'    <vehicle id={quoteattr(vid)} type={quoteattr(tid)} route={quoteattr(vid + "_replay")} '
           f'depart="0" departLane="{lane_index}" departPos="{pos:.3f}" departPosLat="{lat:.3f}" '
           f'departSpeed="{sim.vehicle.getSpeed(vid):.3f}" speedFactor="{sim.vehicle.getSpeedFactor(vid):.4f}"'
           + (' insertionChecks="none"' if exact else '')
           + (">" + "".join(f"\n        {s}" for s in stops) + "\n    </vehicle>" if stops else "/>"))
    return vtype, route, veh, exact


def _parked_lane(sim, vid: str, edges: list[str]) -> str | None:
    """The lane of the stop vehicle ``vid`` stands parked at (off the road), where its remaining route
    ``edges`` begins on that lane's edge; None for one not parked. Departing from the edge after it,
    as a vehicle on no lane does, its stop would be behind it: SUMO refuses to load that ("is not
    downstream the current route")."""
    try:
        if not sim.vehicle.isStoppedParking(vid):
            return None
        stops = sim.vehicle.getStops(vid, 1)
    except Exception:   # gone
        return None
    lane = stops[0].lane if stops else ""
    return lane if lane and edges and lane.rpartition("_")[0] == edges[0] else None


def write_routes(path: str, sim, vehicle_ids, net, vtype_files=None) -> dict[str, bool]:
    """scenario.rou.xml: every given vehicle departing at t = 0 where it stands (on-lane ones at
    their exact lane position and lateral offset). ``vtype_files``: where the scenario's vTypes are
    defined (default: the files the running SUMO loaded). Returns vehicle id -> exact."""
    types, routes, vehicles, exact = {}, [], [], {}
    present = set(sim.vehicle.getIDList())
    declared = declared_vtypes(loaded_files(sim) if vtype_files is None else vtype_files)
    for vid in vehicle_ids:
        if vid not in present:
            continue
        vtype, route, veh, exact[vid] = _vehicle_xml(sim, vid, net, declared)
        types[sim.vehicle.getTypeID(vid)] = vtype
        routes.append(route)
        vehicles.append(veh)
    with open(path, "w") as f:
        f.write("<routes>\n" + "\n".join(list(types.values()) + routes + vehicles) + "\n</routes>\n")
    return exact


FIT_TOLERANCE = 0.1    # m: a departing box centre this close to its pose is left as it is


def fit_departures(config: str, routes_path: str, poses: dict[str, tuple[float, float]]) -> int:
    """Move the departures of ``routes_path`` (written by :func:`write_routes`) so that SUMO inserts
    each box centre at its pose (world x, y by vehicle id); returns how many were moved. A departing
    vehicle takes the heading of its lane from its back to its front, which on a curve (a vehicle
    just past a lane's start, its back on the junction before) is not the heading it stood with, and
    its box swings about its front. SUMO (``config``, the start that loads ``routes_path``) inserts
    them once; each exact departure (``insertionChecks="none"``) whose centre is off is moved along and
    across its lane by the difference, at the heading SUMO gave it, within the lane's room."""
    import re

    from ..core.geometry import sumo_to_pose
    from .sumo import close, start_config
    sim = start_config(config)
    fix: dict[str, tuple[float, float]] = {}
    try:
        sim.simulationStep()
        present = set(sim.vehicle.getIDList())
        for vid, (x, y) in poses.items():
            if vid not in present:
                continue
            fx, fy = sim.vehicle.getPosition(vid)
            cx, cy, _ = sumo_to_pose(fx, fy, sim.vehicle.getAngle(vid), sim.vehicle.getLength(vid))
            ex, ey = x - float(cx), y - float(cy)
            if math.hypot(ex, ey) <= FIT_TOLERANCE:
                continue
            lane = sim.vehicle.getLaneID(vid)
            a = math.radians(90.0 - sim.vehicle.getAngle(vid))
            along, across = ex * math.cos(a) + ey * math.sin(a), -ex * math.sin(a) + ey * math.cos(a)
            room = max(0.0, 0.5 * (sim.lane.getWidth(lane) - sim.vehicle.getWidth(vid)))
            fix[vid] = (min(max(sim.vehicle.getLanePosition(vid) + along, 0.0), sim.lane.getLength(lane)),
                        max(-room, min(room, sim.vehicle.getLateralLanePosition(vid) + across)))
    finally:
        close(sim)

    def moved(m: re.Match) -> str:
        tag = m.group(0)
        if m.group(1) not in fix or 'insertionChecks="none"' not in tag:
            return tag
        pos, lat = fix.pop(m.group(1))
        tag = re.sub(r'departPos="[^"]*"', f'departPos="{pos:.3f}"', tag)
        return re.sub(r'departPosLat="[^"]*"', f'departPosLat="{lat:.3f}"', tag)
    with open(routes_path) as f:
        text = f.read()
    n = len(fix)
    text = re.sub(r'<vehicle id="([^"]+)"[^>]*>', moved, text)
    with open(routes_path, "w") as f:
        f.write(text)
    return n - len(fix)


INPUTS = ("net-file", "route-files", "additional-files")


def write_sumocfg(path: str, options: dict[str, str], state: str | None,
                  routes: list[str] | None = None, begin: float | None = None) -> None:
    """scenario.sumocfg that runs in stock SUMO from wherever the folder is copied: the network and
    the route and additional files travel in the folder (sim.bundle), with the subfolders their
    outputs write into (sim.additional); loads the saved state when given. ``routes``: the route
    files instead of the options' own. ``begin``: the configuration's begin instead of the options'
    (the scene's time); a flow without begin keeps the options' (SUMO's when it loaded the demand),
    written into the folder's copy."""
    from ..core.sumo_xml import option_name, seconds
    here = os.path.dirname(os.path.abspath(path))
    options = {option_name(k): v for k, v in options.items()}
    loaded = seconds(options.get("begin")) or 0.0       # SUMO's default begin: 0
    if begin is not None:
        options["begin"] = f"{begin:g}"
    flow_begin = loaded if begin is not None and begin != loaded else None
    if routes is not None:
        options.pop("route-files", None)
        options = {**options, **({"route-files": ",".join(routes)} if routes else {})}
    lines = ["<configuration>"]
    for name, value in options.items():
        if name in INPUTS:
            if name == "additional-files":
                for sub in {s for v in value.split(",") for s in output_folders(v)}:
                    os.makedirs(os.path.join(here, sub), exist_ok=True)
            value = ",".join(bundle(v, here, includes=name != "net-file",
                                    flow_begin=None if name == "net-file" else flow_begin) for v in value.split(","))
        lines.append(f"    <{name} value={quoteattr(value)}/>")
    if state:
        lines.append(f"    <load-state value={quoteattr(state)}/>")
    lines.append("</configuration>\n")
    with open(path, "w") as f:
        f.write("\n".join(lines))


def write_picture(path: str, seeding, net, ego=None) -> None:
    """scene.png: generated agents, those realising a token, the vehicles kept from the simulation
    (the tokens that are not the user's), the user's tokens circled; ``ego``: scene-frame point to ring."""
    scene = seeding.scene
    user = [t for t, s in zip(seeding.tokens, seeding.token_source) if s == "user"]
    xy = [(t["x"], t["y"]) for t in user if t.get("x") is not None]
    kept = [[t[k] for k in ("x", "y", "heading", "length", "width")]
            for t, s in zip(seeding.tokens, seeding.token_source) if s != "user"]
    kinds = ["generated" if tok is None else "token" for tok in seeding.token_of]
    c = seeding.counts()
    title = (f"{net.name}  seed {seeding.seed}  p_mask {seeding.p_mask:.2f}  agents {c['generated']} "
             f"(placed {c['placed']}, misplaced {c['misplaced']}, refused {c['refused']}, existing {c['existing']}, "
             f"dropped {c['dropped']})")
    img = draw_scene(net, scene, pixels=800, token_xy=np.array(xy).reshape(-1, 2), title=title,
                     kinds=kinds, kept=np.array(kept).reshape(-1, 5), ego=ego)
    write_png(path, img)


class ScenarioWriter:
    def __init__(self, out_dir: str, name: str, force: bool = False):
        self.final = os.path.join(out_dir, name)
        self.tmp = partial_path(self.final)
        if os.path.exists(self.final) and not force:
            raise FileExistsError(f"{self.final}: exists (choose another --output-dir or add --force)")
        shutil.rmtree(self.tmp, ignore_errors=True)
        os.makedirs(self.tmp)
        self.force = force

    def path(self, name: str) -> str:
        return os.path.join(self.tmp, name)

    def after_seeding(self, sim, seeding, net, options: dict[str, str], info: dict,
                      extra_vehicles=()) -> dict:
        """Everything that describes the seeded start (call right after the verification step)."""
        save_state(sim, self.path("state.xml.gz"))     # checked whole: SUMO does not fail where the disk is full
        exact = write_routes(self.path("scenario.rou.xml"), sim, list(seeding.agent_ids) + list(extra_vehicles), net)
        # begun where the state was saved (SUMO warns of a configuration that begins elsewhere)
        write_sumocfg(self.path("scenario.sumocfg"), options, "state.xml.gz", begin=sim.simulation.getTime())
        doc = scene_document(seeding, net, sim, info)
        for a in doc["agents"]:
            a["replay_exact"] = exact.get(a["vehicle"]) if a["vehicle"] else None
        self._json("scene.json", doc)
        # an ego window is centred on the ego (CoSimulation.ego_window), which is one of the kept vehicles
        write_picture(self.path("scene.png"), seeding, net, ego=(0.0, 0.0) if info.get("location") == "ego" else None)
        return doc

    def finish(self, stats: dict) -> str:
        self._json("rollout.json", stats)
        return publish(self.tmp, self.final, replace=self.force)

    def abandon(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)

    def _json(self, name: str, doc: dict) -> None:
        with open(self.path(name), "w") as f:
            json.dump(doc, f, indent=1, default=_plain)


def _plain(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise TypeError(type(v).__name__)


def pose_error(sim, vid: str, agent: dict) -> tuple[float, float]:
    """(metres, radians) between vehicle ``vid`` now and an exported agent's generated pose."""
    x, y = sim.vehicle.getPosition(vid)
    cx, cy, yaw = sumo_to_pose(x, y, sim.vehicle.getAngle(vid), agent["length"])
    return float(np.hypot(cx - agent["x"], cy - agent["y"])), abs(float(wrap_angle(yaw - agent["heading"])))


__all__ = ["ScenarioWriter", "FILES", "pose_error", "write_routes", "write_sumocfg"]
