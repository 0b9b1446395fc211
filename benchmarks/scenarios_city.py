"""City-scale scenarios of the corpus (benchmarks/scenarios.py) whose authors' network is not in their
repository's snapshot (files of 4 MiB and more are absent) and is built here from the sources they ship.

MoST (lcodeca/MoSTScenario, Monaco): its authors build ``most.net.xml`` with ``tools/most.netcfg`` from
``tools/most.raw.osm``, which their merger (``tools/merger/merge.osm.pickles.py``) writes from the OSM-like
files of ``tools/data``, numbering nodes, ways and relations with one counter across all of them. Its
road network is ``tools/data/network.osm``'s 1,525 ways, numbered 152132 to 153656 in document order (the
route and additional files name exactly that range), and its nodes are merged by coordinates (the merger's
key: latitude, longitude, elevation). The build writes that file as the merger does for those ways, runs
the authors' netconvert configuration on it (SUMO's netconvert of today joins a few junctions their older
one did not: 7 of the 5,200 edges the demand names are unknown), and repairs each route through an unknown
edge or a missing connection with the shortest path sumolib finds between the edges around the gap, as
``duarouter --repair`` does. The absent files stay out of the configuration: the persons' demand
(``most.pedestrian.rou.xml``, SAGA's activity-based persons on foot, by bus and by car) and the polygons.
"""
from __future__ import annotations

import re
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

MOST_REPO = "lcodeca/MoSTScenario"
MOST_COMMIT = "b29b2f65f1096a9c69a601ec62a724815cb4a43f"
MOST_FIRST_WAY = 152132       # the merger's number of network.osm's first way (the demand's lowest edge id)
MOST_ROUTES = ["most.buses.flows.xml", "most.trains.flows.xml", "most.commercial.rou.xml",
               "most.special.rou.xml", "most.highway.flows.xml"]
MOST_ADDITIONALS = ["most.busstops.add.xml", "most.trainstops.add.xml", "most.parking.allvisible.add.xml",
                    "basic.vType.xml"]
MOST_ABSENT = ["in/route/most.pedestrian.rou.xml", "in/add/most.poly.xml"]
MOST_TYPEMAPS = ["osmNetconvert", "osmNetconvertUrbanDe", "osmNetconvertPedestrians", "osmNetconvertBicycle",
                 "osmBidiRailNetconvert"]


def most_files() -> dict:
    """The MoST files the build needs: folder path -> (repository path, commit)."""
    files = {"most.sumocfg": "scenario/most.sumocfg", "LICENSE.md": "LICENSE.md",
             "tools/most.netcfg": "tools/most.netcfg", "tools/data/network.osm": "tools/data/network.osm"}
    files.update({f"in/route/{f}": f"scenario/in/route/{f}" for f in MOST_ROUTES})
    files.update({f"in/add/{f}": f"scenario/in/add/{f}" for f in MOST_ADDITIONALS})
    files.update({f"tools/typemap/{t}.typ.xml": f"tools/typemap/{t}.typ.xml" for t in MOST_TYPEMAPS})
    return {k: (v, MOST_COMMIT) for k, v in files.items()}


def _node_key(node: ET.Element) -> str:
    """The merger's key of a node: two nodes at one place and elevation are one."""
    ele = next((t.get("v") for t in node.iter("tag") if t.get("k") == "ele"), "0.0")
    return f"{float(node.get('lat')):.7f}:{float(node.get('lon')):.7f}:{float(ele):.2f}"


def most_raw_osm(src: Path, out: Path, first_way: int = MOST_FIRST_WAY) -> None:
    """``src``'s roads numbered as the authors' merger numbered them (module docstring)."""
    root = ET.parse(src).getroot()
    merged, node_ids, way_ids = {}, {}, {}
    for node in root.findall("node"):
        node_ids[node.get("id")] = merged.setdefault(_node_key(node), node.get("id"))
        if node_ids[node.get("id")] != node.get("id"):
            root.remove(node)
    for i, way in enumerate(root.findall("way")):
        way_ids[way.get("id")] = str(first_way + i)
        way.set("id", way_ids[way.get("id")])
        for nd in way.iter("nd"):
            nd.set("ref", node_ids[nd.get("ref")])
    for member in root.iter("member"):
        ids = way_ids if member.get("type") == "way" else node_ids
        member.set("ref", ids.get(member.get("ref"), member.get("ref")))
    ET.ElementTree(root).write(out, encoding="UTF-8", xml_declaration=True)


def _repaired(edges: list, net, vclass: str | None) -> list | None:
    """A route through unknown edges or missing connections with each gap bridged by a shortest path;
    None when a gap cannot be bridged (SUMO then reports the route, as it does the author's)."""
    known = [e for e in edges if net.hasEdge(e)]
    if not known:
        return None
    out = [known[0]]
    for nxt in known[1:]:
        a, b = net.getEdge(out[-1]), net.getEdge(nxt)
        if a.getConnections(b):
            out.append(nxt)
            continue
        path, _ = net.getShortestPath(a, b, vClass=vclass)
        if path is None:
            return None
        out.extend(e.getID() for e in path[1:])
    return out


ROUTE_EDGES = re.compile(r'(<route\b[^>]*?\bedges=")([^"]*)(")')


def repair_routes(path: Path, net, vclass: str | None = "passenger") -> int:
    """Rewrites the routes of ``path`` the network cannot drive (``_repaired``); the rest of the file is
    kept byte for byte. Returns how many were repaired."""
    text, count = path.read_text(), 0

    def fix(m: re.Match) -> str:
        nonlocal count
        edges = m.group(2).split()
        if all(net.hasEdge(e) for e in edges) and _drivable(edges, net):
            return m.group(0)
        new = _repaired(edges, net, vclass)
        if new is None:
            return m.group(0)
        count += 1
        return m.group(1) + " ".join(new) + m.group(3)

    path.write_text(ROUTE_EDGES.sub(fix, text))
    return count


def _drivable(edges: list, net) -> bool:
    return all(net.getEdge(a).getConnections(net.getEdge(b)) for a, b in zip(edges, edges[1:]))


def _without_absent(cfg: Path, absent: list) -> None:
    """The configuration without the files the snapshot lacks (names in its lists of files)."""
    def drop(m: re.Match) -> str:
        return m.group(1) + ",".join(n for n in m.group(2).split(",") if n.strip() not in absent) + m.group(3)
    cfg.write_text(re.sub(r'(\bvalue=")([^"]*)(")', drop, cfg.read_text()))


def build_most(dest: Path, netconvert: str) -> dict:
    """MoST's network and demand in ``dest`` (the files of ``most_files()`` already there)."""
    import sumolib
    tools = dest / "tools"
    most_raw_osm(tools / "data" / "network.osm", tools / "most.raw.osm")
    subprocess.run([netconvert, "-c", "most.netcfg", "--output-prefix", "", "--output-file", "../in/most.net.xml",
                    "--log", "netconvert.log", "--verbose", "false"],
                   cwd=tools, check=True, capture_output=True, timeout=1800)
    net = sumolib.net.readNet(str(dest / "in" / "most.net.xml"), withPedestrianConnections=False)
    repaired = {f: repair_routes(dest / "in" / "route" / f, net, _vclass(f)) for f in MOST_ROUTES}
    _without_absent(dest / "most.sumocfg", MOST_ABSENT)
    return {"built_with": ["most_raw_osm (scenarios_city.py)", "netconvert -c tools/most.netcfg",
                           "repair_routes"], "routes_repaired": repaired, "left_out": MOST_ABSENT}


def _vclass(route_file: str) -> str:
    return {"most.buses.flows.xml": "bus", "most.trains.flows.xml": "rail"}.get(route_file, "passenger")


# a heavy demand on MoST's network (the corpus's other city rows are light): SUMO's randomTrips, routed by
# duarouter into one route file of 48 MB (90,000 vehicles), 25 departures a second from the fringe
DENSE_TRIPS = ["-b", "0", "-e", "3600", "-p", "0.04", "--seed", "42", "--fringe-factor", "5",
               "--min-distance", "2000"]


def build_most_dense(dest: Path, netconvert: str) -> dict:
    """MoST's network (:func:`build_most`) with a heavy generated demand in ``dense.sumocfg``."""
    import sys

    import sumo
    record = build_most(dest, netconvert)
    tool = Path(sumo.SUMO_HOME) / "tools" / "randomTrips.py"
    subprocess.run([sys.executable, str(tool), "-n", "in/most.net.xml", *DENSE_TRIPS, "-o", "dense.trips.xml",
                    "-r", "dense.rou.xml"], cwd=dest, check=True, capture_output=True, timeout=3600)
    (dest / "dense.sumocfg").write_text(
        '<configuration>\n    <input>\n        <net-file value="in/most.net.xml"/>\n'
        '        <route-files value="dense.rou.xml"/>\n    </input>\n'
        '    <time>\n        <begin value="0"/>\n    </time>\n</configuration>\n')
    return {**record, "demand": ["randomTrips.py", *DENSE_TRIPS, "-r", "dense.rou.xml"]}


# a github source's builder (its ``get["builder"]``), after its files are in the folder
CITY_BUILDERS = {"most": build_most, "most_dense": build_most_dense}
