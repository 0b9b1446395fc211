"""An ASAM OpenSCENARIO file's Init as agent tokens in world coordinates (``--tokens scenario.xosc``).

    data = xosc_tokens("scenario.xosc", net)   # {"frame": "world", "agents": [...]}; XoscError
    spec = load_tokens("scenario.xosc", net)   # the same, checked as a token file (tokens/file.py)

Per Vehicle entity its Init: the TeleportAction's WorldPosition (x, y, h) and the AbsoluteTargetSpeed
of its SpeedAction, with the box of its BoundingBox. OpenSCENARIO places a vehicle by its reference
point; the token is the box's centre, the BoundingBox's Center turned by h from that point. A file
this project wrote records in its FileHeader Properties the offset of its OpenDRIVE from the SUMO
network (``opendrive_offset_x/y``, docs/openscenario.md), taken off here; any other file is read in the
network's coordinates. Plain XML (ElementTree): generation does not depend on scenariogeneration.
Parameters (``$name``) are read from the file's global ParameterDeclarations; only world positions
are read (a lane or road position needs the OpenDRIVE's geometry), and every position must lie on the
network (a car lane or a junction) when a network is given.
"""
from __future__ import annotations

import math
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


def _agent(name: str, private: ET.Element, box, values: _Values, offset) -> dict:
    where = f"Init: entity {name!r}"
    agent = {}
    for action in private.iter("TeleportAction"):
        pos = action.find("Position")
        kind = pos[0].tag if pos is not None and len(pos) else None
        if kind != "WorldPosition":
            raise _error(values.source, where, f"{kind or 'no position'}: only WorldPosition is read "
                         f"(x, y, h in the network's coordinates)")
        wp = pos[0]
        h = values.number(wp, "h", where, 0.0)
        x, y = values.number(wp, "x", where) - offset[0], values.number(wp, "y", where) - offset[1]
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
    boxes, offset = _boxes(root, values), _offset(root, values)
    agents, names = [], []
    for private in init.findall("Actions/Private"):
        name = private.get("entityRef")
        if name in boxes:
            agent = _agent(name, private, boxes[name], values, offset)
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
