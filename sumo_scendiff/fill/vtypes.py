"""The demand's vehicle types as SUMO reads them: each vType's own values, else SUMO's defaults for
its vClass (sumo.dlr.de "Vehicle Type Parameter Defaults", ``SUMOVTypeParameter``'s
``VClassDefaultValues``).

    bodies = vtype_bodies(route_and_additional_files)   # vType id -> Body(length, width, min_gap)
    bodies.get(type_id, DEFAULT_BODY).spacing           # m of lane it takes standing in a queue
    vtype_table(files, of)                              # of(<vType>) per id, distributions included
"""
from __future__ import annotations

from dataclasses import dataclass

from ..sim.fleet import DEFAULT_MIN_GAP   # SUMO's default vType's

# per vClass: maxSpeed (m/s), accel, decel (m/s²), length and width (m); minGap 2.5 m but a bicycle's
CLASS_MAX_SPEED = {"passenger": 55.56, "private": 55.56, "taxi": 55.56, "evehicle": 55.56,
                   "delivery": 55.56, "emergency": 55.56, "authority": 55.56, "army": 55.56,
                   "vip": 55.56, "truck": 36.11, "trailer": 36.11, "bus": 27.78, "coach": 27.78,
                   "motorcycle": 55.56, "moped": 13.89}
CLASS_ACCEL = {"truck": 1.3, "trailer": 1.1, "bus": 1.2, "coach": 2.0, "moped": 1.1}
CLASS_DECEL = {"truck": 4.0, "trailer": 4.0, "bus": 4.0, "coach": 4.0, "moped": 7.0}
CLASS_SIZE = {"passenger": (5.0, 1.8), "private": (5.0, 1.8), "taxi": (5.0, 1.8), "evehicle": (5.0, 1.8),
              "delivery": (6.5, 2.16), "emergency": (6.5, 2.16), "authority": (5.0, 1.8),
              "army": (5.0, 1.8), "vip": (5.0, 1.8), "custom1": (5.0, 1.8), "custom2": (5.0, 1.8),
              "truck": (7.1, 2.4), "trailer": (16.5, 2.55), "bus": (12.0, 2.5), "coach": (14.0, 2.6),
              "motorcycle": (2.2, 0.9), "moped": (2.1, 0.8), "bicycle": (1.6, 0.65)}
CLASS_MIN_GAP = {"bicycle": 0.5}


@dataclass(frozen=True)
class Body:
    """A vehicle's extent on its lane (m)."""

    length: float
    width: float
    min_gap: float = DEFAULT_MIN_GAP

    @property
    def spacing(self) -> float:
        """Lane it takes standing in a queue: its length and the gap it keeps to the one ahead."""
        return self.length + self.min_gap


DEFAULT_BODY = Body(*CLASS_SIZE["passenger"])   # SUMO's DEFAULT_VEHTYPE


def number(el, name: str, default: float) -> float:
    """``el``'s attribute ``name`` as a number (a distribution such as "normc(1,0.1,0.2,2)": its
    mean), else ``default``."""
    v = el.get(name)
    try:
        return float(v) if v is not None else default
    except ValueError:
        head = v.split("(", 1)[-1].split(",")[0]
        try:
            return float(head)
        except ValueError:
            return default


def vtype_bodies(paths) -> dict[str, Body]:
    """The :class:`Body` of every vType in ``paths`` (route and additional files) by id, and of every
    vTypeDistribution (its first member's)."""
    def body(el) -> Body:
        cls = el.get("vClass") or "passenger"
        length, width = CLASS_SIZE.get(cls, CLASS_SIZE["passenger"])
        return Body(number(el, "length", length), number(el, "width", width),
                    number(el, "minGap", CLASS_MIN_GAP.get(cls, DEFAULT_MIN_GAP)))
    return vtype_table(paths, body)


def vtype_table(paths, of) -> dict:
    """``of(element)`` (an ElementTree element) of every vType in ``paths`` (route and additional
    files, read as SUMO reads them: core.sumo_xml) by id, and of every vTypeDistribution (its first
    member's; a distribution lists members or holds vTypes)."""
    from ..core.sumo_xml import elements
    from ..sim.fleet import vtype_distributions
    out: dict = {}
    for _, el in elements(paths, ("vType", "vTypeDistribution")):
        for vt in ([el] if el.tag == "vType" else el.findall("vType")):
            if vt.get("id"):
                out[vt.get("id")] = of(vt)
    for name, members in vtype_distributions(paths).items():
        first = next((m for m in members if m in out), None)
        if first is not None and name not in out:
            out[name] = out[first]
    return out


__all__ = ["CLASS_ACCEL", "CLASS_DECEL", "CLASS_MAX_SPEED", "CLASS_MIN_GAP", "CLASS_SIZE", "DEFAULT_BODY",
           "DEFAULT_MIN_GAP", "Body", "number", "vtype_bodies", "vtype_table"]
