"""The demand's flows numbered on in the fill's folder as SUMO's own run numbers them.

    number_flows(folder, state_time)     # after write_configurations: both .sumocfg files load FILE

SUMO names a flow's vehicles ``<flow>.<index>``, the index counting the vehicles the flow made
(``MSInsertionControl``), and a flow loaded with ``--begin`` after its own begin skips the departures
before it without counting them: its first vehicle is ``f.0`` again where SUMO's own run has ``f.12``.
Only a saved state carries the count on (``<flowState index=...>``); stock SUMO has no attribute for a
flow's first index. So a flow of fixed departures (``period``, ``vehsPerHour``, ``number``) that
departed before the folder's time is taken out of the folder's copies of the files and its departures
from then on written one by one, under the ids SUMO's own run gives them, into :data:`FILE` (sorted by
departure, loaded after the demand's files): the portable start names them as the user's run does, and a
start from the state too (its flowState of a flow no file defines makes nothing). A random flow
(``probability``, ``period="exp(...)"``) keeps its own numbering (its departures are SUMO's draws,
known only by running on), as does every flow where ``--scale`` is not 1: SUMO scales a flow's period
without chance but a single vehicle by chance, so departures written one by one would be scaled again
(docs/fill.md).
"""
from __future__ import annotations

import copy
import gzip
import math
import os
import xml.etree.ElementTree as ET

FILE = "flow_departures.rou.xml"
DAY_MS = 86_400_000     # a flow that gives no end ends this long after its begin, where SUMO's --end is not set
# a flow's attributes that say when it departs; the rest are each vehicle's
_TIMING = ("id", "begin", "end", "period", "vehsPerHour", "number", "probability", "perHour")
# a flow that gives no route but where it goes: its vehicles are trips
_TRIP = ("from", "to", "fromJunction", "toJunction", "fromTaz", "toTaz", "fromXY", "toXY", "fromLonLat", "toLonLat")


def _ms(value: str | None) -> int | None:
    """A SUMO time in ms (``TIME2STEPS``: rounded), None for none or a non-number."""
    from ..core.sumo_xml import seconds
    t = seconds(value)
    return None if t is None else int(math.floor(t * 1000.0 + 0.5))


def departures(flow: dict, sim_end: str | None = None) -> list[int] | None:
    """The departure times (ms) of a ``<flow>`` (attribute dict) of fixed departures, in order, as
    SUMO spaces them (each the one before plus the period in whole ms; ``number`` over begin..end:
    that span divided in whole ms); None for a random flow or one SUMO would not read. A flow without
    an end ends at the simulation's ``sim_end`` (its ``--end``) where one is set, else a day after its
    begin (as SUMO 1.28 runs them)."""
    begin = _ms(flow.get("begin", "0"))
    number = int(flow["number"]) if str(flow.get("number", "")).isdigit() else None
    if begin is None or flow.get("probability") is not None or flow.get("perHour") is not None:
        return None
    end, until = _ms(flow.get("end")), _ms(sim_end)
    if end is None:     # SUMO's --end is -1 where none is set
        end = until if until is not None and until >= 0 else begin + DAY_MS
    if flow.get("vehsPerHour") is not None:
        vph = float(flow["vehsPerHour"])
        period = int(math.floor(3_600_000.0 / vph + 0.5)) if vph > 0 else None
    elif flow.get("period") is not None:
        period = _ms(flow["period"])                  # "exp(0.1)": random, None
    elif number:
        period = (end - begin) // number
    else:
        return None
    if not period or period <= 0:
        return None
    count = number if number is not None else math.ceil((end - begin) / period)
    return [begin + k * period for k in range(count)]


def _vehicles(flow: ET.Element, times: list[int], first: int) -> list[tuple[int, ET.Element]]:
    """The flow's departures at ``times`` (ms), named from index ``first`` on, as vehicles or trips."""
    attrs = {k: v for k, v in flow.attrib.items() if k not in _TIMING}
    routed = "route" in attrs or flow.find("route") is not None or not any(k in attrs for k in _TRIP)
    out = []
    for k, t in enumerate(times):
        el = ET.Element("vehicle" if routed else "trip", {"id": f"{flow.get('id')}.{first + k}",
                                                          "depart": f"{t / 1000.0:.3f}", **attrs})
        el.extend(copy.deepcopy(list(flow)))
        el.text, el.tail = flow.text, "\n    "
        out.append((t, el))
    return out


def _renumber_file(path: str, state_ms: int, sim_end: str | None) -> list[tuple[int, ET.Element]]:
    """The flows of fixed departures of file ``path`` that departed before ``state_ms``, taken out of it
    (the file rewritten, not through a link it shares); their departures from then on as elements. Read
    and written in a stream (a city's route file is large; its DOM was 3.5 times its size)."""
    try:
        out, drop = _early_flows(path, state_ms, sim_end)
    except ET.ParseError:   # a file cut short: SUMO reads it to the cut (data.demand), its flows left as given
        return []
    if out:
        tmp = path + ".tmp"
        with (gzip.open(tmp, "wb") if path.endswith(".gz") else open(tmp, "wb")) as f:
            _write_without(path, drop, f)
        os.replace(tmp, path)
    return out


def _top_level(path: str):
    """(event, position, element) of ``path``'s root ("root", -1, root) at its start, then of each of its
    children: ("start", k, child) when it begins, ("end", k, child) when it is whole, and the root's
    ("close", -1, root) at its end; each child let go once the next begins (its tail is known by then)."""
    from ..core.sumo_xml import open_xml
    depth, pos, root, done = 0, -1, None, None
    with open_xml(path) as f:
        for event, el in ET.iterparse(f, events=("start", "end")):
            depth += 1 if event == "start" else -1
            if event == "start" and depth == 1:
                root = el
                yield "root", -1, el
            elif event == "start" and depth == 2:
                if done is not None:
                    root.remove(done)
                pos += 1
                yield "start", pos, el
            elif event == "end" and depth == 1:
                done = el
                yield "end", pos, el
            elif event == "end" and depth == 0:
                yield "close", -1, el


def _early_flows(path: str, state_ms: int, sim_end: str | None) -> tuple[list[tuple[int, ET.Element]], set[int]]:
    """The departures from ``state_ms`` on of ``path``'s flows of fixed departures that departed before it
    (:func:`_vehicles`), and those flows' positions among the root's children."""
    out, drop = [], set()
    for event, pos, el in _top_level(path):
        if event != "end" or el.tag != "flow":
            continue
        times = departures(el.attrib, sim_end)
        before = sum(t < state_ms for t in times) if times else 0
        if before:
            out += _vehicles(el, times[before:], before)
            drop.add(pos)
    return out, drop


def _write_without(path: str, drop: set[int], f) -> None:
    """``path`` written to binary ``f`` without its root's children at positions ``drop``, as
    ElementTree writes the whole tree (declaration, the root's namespaces, each child with its tail)."""
    root, last, wrote = None, None, False
    for event, pos, el in _top_level(path):
        if event == "root":
            root = el
        if event in ("start", "close") and last is not None and last[0] not in drop:
            if not wrote:
                f.write(_root_tags(root, True)[0])
            f.write(ET.tostring(last[1], encoding="unicode").encode("utf-8"))
            wrote = True
        last = (pos, el) if event == "end" else None if event == "start" else last
        if event == "close":
            f.write(_root_tags(root, True)[1] if wrote else _root_tags(root, False)[0])


def _root_tags(root: ET.Element, children: bool) -> tuple[bytes, bytes]:
    """What ElementTree writes of ``root`` before its first child (declaration, start tag, text) and after
    its last (end tag, tail); without ``children``, all it writes of the root left with none."""
    import io
    shell = ET.Element(root.tag, root.attrib)
    shell.text, shell.tail = root.text, root.tail
    if children:
        ET.SubElement(shell, "split")
    buf = io.BytesIO()
    ET.ElementTree(shell).write(buf, encoding="UTF-8", xml_declaration=True)
    head, _, tail = buf.getvalue().partition(b"<split />")
    return head, tail


def _configured(config: str) -> dict[str, str]:
    """A .sumocfg's options (name -> value), as the fill writes them (sim.export.write_sumocfg)."""
    return {el.tag: el.get("value", "") for el in ET.parse(config).getroot()}


def number_flows(folder: str, state_time: float, skip=("start.rou.xml", "inflow.rou.xml")) -> int:
    """The folder's flows of fixed departures that departed before ``state_time`` written one by one
    from then on under SUMO's own ids into :data:`FILE`, which both configurations load after the
    demand's files; returns how many departures (0: nothing changed)."""
    configs = [os.path.join(folder, n) for n in ("scenario.sumocfg", "start.sumocfg")]
    options = _configured(configs[1])
    try:
        if abs(float(options.get("scale", "1")) - 1.0) > 1e-9:
            return 0
    except ValueError:
        return 0
    names = [n for key in ("route-files", "additional-files") for n in options.get(key, "").split(",")
             if n and n not in skip and os.path.isfile(os.path.join(folder, n))]
    state_ms = int(math.floor(state_time * 1000.0 + 0.5))
    found = sorted((pair for n in dict.fromkeys(names)
                    for pair in _renumber_file(os.path.join(folder, n), state_ms, options.get("end"))),
                   key=lambda pair: pair[0])
    if not found:
        return 0
    root = ET.Element("routes")
    root.text = "\n    "
    root.extend(el for _, el in found)
    found[-1][1].tail = "\n"
    ET.ElementTree(root).write(os.path.join(folder, FILE), encoding="UTF-8", xml_declaration=True)
    for config in configs:
        _load_after(config, FILE)
    return len(found)


def _load_after(config: str, name: str) -> None:
    """``config`` loading route file ``name`` after its others."""
    tree = ET.parse(config)
    el = tree.getroot().find("route-files")
    if el is None:
        el = ET.SubElement(tree.getroot(), "route-files")
    el.set("value", ",".join([v for v in el.get("value", "").split(",") if v] + [name]))
    tree.write(config, encoding="UTF-8")


__all__ = ["FILE", "departures", "number_flows"]
