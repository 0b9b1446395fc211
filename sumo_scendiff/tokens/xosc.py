"""An ASAM OpenSCENARIO file's Init as agent tokens in world coordinates (``--tokens scenario.xosc``).

    data = xosc_tokens("scenario.xosc", net)   # {"frame": "world", "agents": [...]}; XoscError
    spec = load_tokens("scenario.xosc", net)   # the same, checked as a token file (tokens/file.py)

Per Vehicle entity its Init: the TeleportAction's WorldPosition (x, y, h) and the AbsoluteTargetSpeed
of its SpeedAction, with the box of its BoundingBox. OpenSCENARIO places a vehicle by its reference
point; the token is the box's centre, the BoundingBox's Center turned by h from that point. A file
this project wrote records in its FileHeader Properties the offset of its OpenDRIVE from the SUMO
network (``opendrive_offset_x/y``, docs/openscenario.md), taken off here; any other file is read in the
network's coordinates. A LanePosition is read where the file's OpenDRIVE is netconvert's own (each
road names its SUMO edge): on the SUMO lane it stands for. Plain XML (ElementTree): generation does
not depend on scenariogeneration. Parameters (``$name``) are read from the file's global
ParameterDeclarations; other positions (road, relative, route, geographic) are not read, and every
position must lie on the network (a car lane or a junction) when a network is given.
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET


POSITIONS = ("WorldPosition", "LanePosition", "RoadPosition", "RelativeWorldPosition", "RelativeObjectPosition",
             "RelativeLanePosition", "RelativeRoadPosition", "RoutePosition", "GeoPosition", "TrajectoryPosition")


class XoscError(ValueError):
    """An OpenSCENARIO file that gives no tokens; the one-line message starts with the file path."""


def _error(source: str, *parts) -> XoscError:
    return XoscError(": ".join(str(p) for p in (source, *parts)).replace("\n", " "))


class _Values:
    """Attribute values with the file's global parameters resolved."""

    def __init__(self, root: ET.Element, source: str):
        self.source = source
        self.params = {p.get("name", "").lstrip("$"): p.get("value", "")
                       for p in root.findall("ParameterDeclarations/ParameterDeclaration")}

    def number(self, el: ET.Element, name: str, where: str, default: float | None = None) -> float | None:
        raw = el.get(name)
        if raw is None:
            return default
        if raw.startswith("${"):
            raise _error(self.source, where, f"{name}={raw!r}: parameter expressions are not read")
        if raw.startswith("$"):
            if raw[1:] not in self.params:
                raise _error(self.source, where, f"{name}={raw!r}: no such parameter declared")
            raw = self.params[raw[1:]]
        try:
            value = float(raw)
        except ValueError:
            raise _error(self.source, where, f"{name}={raw!r}: not a number") from None
        if not math.isfinite(value):
            raise _error(self.source, where, f"{name}={raw!r}: not a finite number")
        return value


def _boxes(root: ET.Element, values: _Values) -> dict[str, tuple | None]:
    """Vehicle entity name -> (length, width, centre x, centre y) of its BoundingBox (None: a
    catalog reference, whose box is in another file)."""
    out = {}
    for obj in root.findall("Entities/ScenarioObject"):
        name, veh = obj.get("name"), obj.find("Vehicle")
        if veh is None:
            if obj.find("CatalogReference") is not None:
                out[name] = None
            continue
        box, where = veh.find("BoundingBox"), f"entity {name!r}"
        if box is None:
            out[name] = None
            continue
        dim, centre = box.find("Dimensions"), box.find("Center")
        out[name] = (values.number(dim, "length", where), values.number(dim, "width", where),
                     values.number(centre, "x", where, 0.0), values.number(centre, "y", where, 0.0))
    return out


def _offset(root: ET.Element, values: _Values) -> tuple[float, float]:
    props = {p.get("name"): p for p in root.findall("FileHeader/Properties/Property")}
    return tuple(values.number(props[k], "value", "FileHeader") if k in props else 0.0
                 for k in ("opendrive_offset_x", "opendrive_offset_y"))


class _Roads:
    """netconvert's OpenDRIVE the file names (its LogicFile, read once): road id -> (SUMO edge, the
    road's length), from the ``sumoId`` userData that ``--output.original-names`` writes."""

    def __init__(self, root: ET.Element, source: str):
        self.source, self.root, self._roads = source, root, None

    def road(self, road_id: str, where: str) -> tuple[str, float]:
        if self._roads is None:
            logic = self.root.find("RoadNetwork/LogicFile")
            if logic is None or not logic.get("filepath"):
                raise _error(self.source, where, "LanePosition: the file names no OpenDRIVE (RoadNetwork LogicFile)")
            path = os.path.join(os.path.dirname(os.path.abspath(self.source)), logic.get("filepath"))
            try:
                roads = ET.parse(path).getroot().findall("road")
            except (OSError, ET.ParseError) as e:
                raise _error(self.source, where, f"LanePosition: its OpenDRIVE {logic.get('filepath')}: "
                             f"not readable ({e})") from None
            self._roads = {r.get("id"): (u.get("value"), float(r.get("length"))) for r in roads
                           for u in r.findall("userData[@code='sumoId']")}
        if road_id not in self._roads:
            raise _error(self.source, where, f"LanePosition: road {road_id!r} has no SUMO edge (lane positions "
                         f"are read on netconvert's own OpenDRIVE, --output.original-names)")
        return self._roads[road_id]


def _lane_position(lp: ET.Element, values: _Values, roads: _Roads, net, where: str) -> tuple[float, float, float]:
    """A LanePosition on netconvert's OpenDRIVE as world x, y, h: its road is a SUMO edge, OpenDRIVE
    lane -k that edge's lane n - k (netconvert numbers right lanes from the centre outwards, SUMO from
    the outer edge inwards), s scaled from the road's length to the lane's."""
    if net is None:
        raise _error(values.source, where, "LanePosition: needs the network to be read")
    edge, road_len = roads.road(lp.get("roadId"), where)
    lanes = [ln for ln in net.lanes if ln.edge == edge]
    k = int(values.number(lp, "laneId", where))
    index = max((ln.index for ln in lanes), default=-1) + 1 + k
    lane = next((i for i, ln in enumerate(net.lanes) if ln.edge == edge and ln.index == index), None)
    if k >= 0 or lane is None:
        raise _error(values.source, where, f"LanePosition: lane {k} of road {lp.get('roadId')!r} is no lane "
                     f"of SUMO edge {edge!r}")
    s, t = values.number(lp, "s", where), values.number(lp, "offset", where, 0.0)
    xy, yaw = net.lane_pose(lane, s * net.lanes[lane].length / road_len)
    orient = lp.find("Orientation")
    h = values.number(orient, "h", where, 0.0) if orient is not None else 0.0
    h = h if orient is not None and orient.get("type") == "absolute" else yaw + h
    return float(xy[0] - t * math.sin(yaw)), float(xy[1] + t * math.cos(yaw)), h


def _agent(name: str, private: ET.Element, box, values: _Values, offset, roads: _Roads, net) -> dict:
    where = f"Init: entity {name!r}"
    agent = {}
    for action in private.iter("TeleportAction"):
        pos = action.find("Position")
        kind = pos[0].tag if pos is not None and len(pos) else None
        if kind == "LanePosition":
            x, y, h = _lane_position(pos[0], values, roads, net, where)
        elif kind == "WorldPosition":
            wp = pos[0]
            h = values.number(wp, "h", where, 0.0)
            x, y = values.number(wp, "x", where) - offset[0], values.number(wp, "y", where) - offset[1]
        else:
            raise _error(values.source, where, f"{kind or 'no position'}: only WorldPosition (and LanePosition "
                         f"on netconvert's OpenDRIVE) is read")
        if box is not None:   # the reference point -> the box's centre
            x += box[2] * math.cos(h) - box[3] * math.sin(h)
            y += box[2] * math.sin(h) + box[3] * math.cos(h)
            agent.update(length=box[0], width=box[1])
        agent.update(x=x, y=y, heading=math.atan2(math.sin(h), math.cos(h)))
    for target in private.iter("AbsoluteTargetSpeed"):
        agent["speed"] = values.number(target, "value", where)
    return agent


def xosc_tokens(path: str, net=None) -> dict:
    """The Init of OpenSCENARIO file ``path`` as a world-frame token table; with ``net`` (a
    :class:`~sumo_scendiff.map.network.Network`) every position is checked to lie on it."""
    source = str(path)
    try:
        root = ET.parse(path).getroot()
    except FileNotFoundError:
        raise _error(source, "no such file") from None
    except (ET.ParseError, OSError) as e:
        raise _error(source, f"not readable XML ({e})") from None
    if root.tag != "OpenSCENARIO":
        raise _error(source, f"not an OpenSCENARIO file (root element <{root.tag}>)")
    init = root.find("Storyboard/Init")
    if init is None:
        raise _error(source, "no Storyboard Init (nothing places a vehicle)")
    values = _Values(root, source)
    boxes, offset, roads = _boxes(root, values), _offset(root, values), _Roads(root, source)
    agents, names = [], []
    for private in init.findall("Actions/Private"):
        name = private.get("entityRef")
        if name in boxes:
            agent = _agent(name, private, boxes[name], values, offset, roads, net)
            if "x" in agent:
                agents.append(agent)
                names.append(name)
    if not agents:
        raise _error(source, "Init: no vehicle is placed (no TeleportAction of a Vehicle entity)")
    if net is not None:
        _on_network(source, net, agents, names)
    return {"frame": "world", "agents": agents}


def _on_network(source: str, net, agents: list[dict], names: list[str]) -> None:
    on = net.on_drivable([[a["x"], a["y"]] for a in agents])
    for a, name, ok in zip(agents, names, on):
        if not ok:
            raise _error(source, f"Init: entity {name!r}", f"world position ({a['x']:.2f}, {a['y']:.2f}) is off "
                         f"the network {net.name} (on no car lane or junction)")
