"""A SUMO network as OpenDRIVE: netconvert's own conversion, once per network (cached by the file's
sha256), with what puts it in the network's coordinates.

    od = opendrive_for("city.net.xml.gz")   # OpenDrive(path=<cache>/<sha>.xodr, info={...})
    od.place("out/scene_000/scenario.xodr")

netconvert writes OpenDRIVE 1.4 from a ``.net.xml`` in the network's own coordinates (it sets
``offset.disable-normalization`` when reading one): its header's west/south are the network's
``convBoundary`` minimum. ``info["offset"]`` is measured, not assumed: OpenDRIVE minus network
coordinates, from the header's bounds against the network's ``convBoundary``; SUMO's ``netOffset``
and projection are recorded too (netconvert writes the projection as ``geoReference`` and, for a
projected network, OpenDRIVE 1.6's header ``<offset>`` = −netOffset: a geographic position is
``xodr - offset - netOffset`` projected back). ``--output.original-names``
puts each SUMO edge id in its road's ``userData`` (road and lane positions can be mapped back).
"""
from __future__ import annotations

import gzip
import json
import os
import shutil
import subprocess
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from ..core.files import file_sha256
from ..core.outputs import partial_path
from ..core.tools import sumo_binary
from .schema import SchemaMissing, installed_opendrive, opendrive_xsd, schema_errors


class ExportError(ValueError):
    """An input the export cannot use (one line: the file and the problem)."""


@dataclass(frozen=True)
class OpenDrive:
    path: str      # the cached conversion (read-only)
    info: dict     # netconvert's version, the offset, the schema check

    def place(self, target: str) -> None:
        """The conversion at ``target``, hard-linked from the cache where the file system allows
        (a city's OpenDRIVE is megabytes; a sweep has one per scene), else copied."""
        if os.path.exists(target) and os.path.samefile(self.path, target):
            return    # linked by an export before (--force): a rename onto its own link would leave tmp beside it
        tmp = partial_path(target)
        try:
            os.link(self.path, tmp)
        except OSError:
            shutil.copyfile(self.path, tmp)
        os.replace(tmp, target)


def cache_dir() -> str:
    """Where converted OpenDRIVE networks are kept (core.files.cache_dir)."""
    from ..core.files import cache_dir as project_cache
    return project_cache("opendrive")


_MEMO: dict[str, OpenDrive] = {}
CACHE_VERSION = 2


def opendrive_for(net: str) -> OpenDrive:
    """The OpenDRIVE of network file ``net``: from this process's memo, the cache, or netconvert."""
    key = file_sha256(net)
    if key in _MEMO:
        return _MEMO[key]
    folder = cache_dir()
    os.makedirs(folder, exist_ok=True)
    name = os.path.join(folder, f"{key}-v{CACHE_VERSION}")   # a new description: a new entry
    xodr, meta = f"{name}.xodr", f"{name}.json"
    if not (os.path.isfile(xodr) and os.path.isfile(meta)):
        _convert(net, xodr)
        info = describe(net, xodr)
        tmp = partial_path(meta)
        with open(tmp, "w") as f:
            json.dump(info, f, indent=1)
        os.replace(tmp, meta)
    with open(meta) as f:
        _MEMO[key] = OpenDrive(xodr, json.load(f))
    return _MEMO[key]


def _convert(net: str, xodr: str) -> None:
    tmp = partial_path(xodr)
    cmd = [sumo_binary("netconvert"), "-s", net, "--opendrive-output", tmp, "--output.original-names", "true",
           "--no-warnings", "true"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    except (OSError, subprocess.SubprocessError) as e:
        raise ExportError(f"{net}: netconvert did not run ({e})") from None
    if done.returncode != 0 or not os.path.isfile(tmp):
        if os.path.exists(tmp):
            os.remove(tmp)
        lines = [ln.strip() for ln in (done.stderr + done.stdout).splitlines() if ln.startswith("Error")]
        why = lines[0].removeprefix("Error:").strip() if lines else \
            f"netconvert died (signal {-done.returncode})" if done.returncode < 0 else f"exit code {done.returncode}"
        raise ExportError(f"{net}: netconvert cannot convert it to OpenDRIVE: {why}")
    os.chmod(tmp, 0o444)   # shared by hard links: an edit in one scene folder must not change the others
    os.replace(tmp, xodr)


def _open(path: str):
    return gzip.open(path, "rb") if path.endswith(".gz") else open(path, "rb")


def _first(path: str, tag: str) -> ET.Element | None:
    with _open(path) as f:
        for _, el in ET.iterparse(f, events=("end",)):
            if el.tag == tag:
                return el
    return None


def _numbers(text: str) -> list[float]:
    return [float(v) for v in text.split(",")]


def describe(net: str, xodr: str) -> dict:
    """What the conversion is: netconvert's version, OpenDRIVE revision, the offset to the network's
    coordinates, SUMO's netOffset and projection, and the check against the installed schema."""
    loc, header = _first(net, "location"), _first(xodr, "header")
    if loc is None or header is None:
        raise ExportError(f"{net}: no <location> in the network or no <header> in its OpenDRIVE")
    conv = _numbers(loc.get("convBoundary", "0,0,0,0"))
    offset = [float(header.get("west", conv[0])) - conv[0], float(header.get("south", conv[1])) - conv[1]]
    geo, shift = header.find("geoReference"), header.find("offset")
    version = subprocess.run([sumo_binary("netconvert"), "--version"], capture_output=True, text=True).stdout
    revision = (int(header.get("revMajor", 1)), int(header.get("revMinor", 4)))
    return {"netconvert": version.splitlines()[0].strip() if version else None,
            "network_sha256": file_sha256(net), "opendrive": f"{revision[0]}.{revision[1]}",
            "offset": [round(v, 6) for v in offset],
            "offset_meaning": "OpenDRIVE x, y minus SUMO network x, y (the network's own coordinates: 0, 0)",
            "net_offset": _numbers(loc.get("netOffset", "0,0")),
            "projection": loc.get("projParameter", "!"),
            "geo_reference": (geo.text or "").strip() if geo is not None else None,
            # netconvert writes OpenDRIVE 1.6's header <offset> (minus the netOffset) for a projected
            # network: the roads' coordinates plus it are the projection's; it does not move the roads
            "header_offset": {k: float(shift.get(k, 0)) for k in ("x", "y", "z", "hdg")} if shift is not None else None,
            "schema": _schema_check(xodr, revision)}


def _schema_check(xodr: str, revision: tuple[int, int]) -> dict:
    """Against the schema of the revision netconvert writes, where scenariogeneration ships it; else
    against the newest it ships, for information only (1.7 made attributes 1.4 leaves optional required)."""
    try:
        xsd, exact = opendrive_xsd(*revision), True
    except SchemaMissing:
        shipped = installed_opendrive()
        if not shipped:
            return {"checked": False, "reason": "no OpenDRIVE schema installed"}
        major, minor = shipped[-1].split(".")
        xsd, exact = opendrive_xsd(int(major), int(minor)), False
    n, first = schema_errors(xodr, xsd)
    return {"checked": True, "schema": os.path.basename(xsd), "same_revision": exact, "valid": n == 0,
            "errors": n, "first_errors": first}
