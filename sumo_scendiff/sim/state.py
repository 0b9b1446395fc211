"""A SUMO state saved so that SUMO loads it again.

    save_state(sim, "state.xml.gz")     # saveState, the routes it left out added, checked whole
    waiting_in_state("state.xml.gz", sim.vehicle.getIDList(), t)   # loaded, due, not yet on the road
    in_process_state("state.xml.gz")    # what libsumo loads of it: a copy without rail sub-driveways

SUMO 1.28 writes a route into a state with the vehicle it was made for: a vehicle that shares that
route and is still driving after its owner arrived -- the copies ``--scale`` makes of a vehicle (ids
``pas4.1``, route ``!pas4``) -- is saved naming a route the state no longer defines, and
``sumo --load-state`` refuses the file ("The route '!pas4' for vehicle 'pas4.1' is not known"), stock
SUMO's own round trip included. Each such route is written into the state from the running simulation.

SUMO 1.28's libsumo crashes (a segfault, the process gone) on a later start in the same process from a
state that holds a rail signal's sub-driveway (``<subDriveWay>``: a train that departed inside a block);
SUMO rebuilds them as its trains drive on, and stock SUMO drives the same with and without them
(measured: FCD byte-identical, tests/test_state_subdriveway.py). The saved state keeps them for stock
SUMO; what libsumo loads is a copy without them (:func:`in_process_state`).
"""
from __future__ import annotations

import atexit
import gzip
import os
import re
import shutil
import tempfile

from ..core.files import check_whole

_ROUTE = re.compile(rb'<route id="([^"]*)"')
_VEHICLE_ROUTE = re.compile(rb'<vehicle id="([^"]*)"[^>]*? route="([^"]*)"')
_VEHICLE_DEPART = re.compile(rb'<vehicle id="([^"]*)"[^>]*? depart="([^"]*)"')
_SUB_DRIVE_WAY = re.compile(rb'[ \t]*<subDriveWay [^>]*/>[ \t]*\r?\n?')
_copies: dict[tuple, str] = {}     # (path, mtime, size) -> what libsumo loads of it (itself or a copy)
_folder: list[str] = []             # where those copies lie


def save_state(sim, path: str) -> str:
    """``sim``'s state saved to ``path`` (gzip by its name, as SUMO), every route its vehicles name
    defined in it; raises core.files' error where the disk left the file short. Returns ``path``."""
    sim.simulation.saveState(path)
    check_whole(path)
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rb") as f:
        text = f.read()
    defined = set(_ROUTE.findall(text))
    # a route SUMO dropped with its owner is no longer known by its id: its edges are the vehicle's
    missing = {r: v for v, r in _VEHICLE_ROUTE.findall(text) if r not in defined}
    if missing:
        lines = b"".join(b'    <route id="%s" state="0" edges="%s"/>\n'
                         % (r, " ".join(sim.vehicle.getRoute(v.decode())).encode()) for r, v in sorted(missing.items()))
        at = text.index(b"<vehicle ")
        at = text.rindex(b"\n", 0, at) + 1
        with opener(path, "wb") as f:
            f.write(text[:at] + lines + text[at:])
    return path


def waiting_in_state(path: str, on_network, time: float) -> int:
    """The vehicles a saved state holds that were due by ``time`` and are not among ``on_network``
    (the vehicles in the network when it was saved): those waiting to enter. SUMO loads them into its
    insertion queue only at the next step (``getPendingVehicles`` is empty right after a state is
    loaded), so a simulation started from a state cannot count them itself."""
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rb") as f:
        text = f.read()
    there = set(on_network)
    return sum(1 for v, depart in _VEHICLE_DEPART.findall(text)
               if v.decode() not in there and float(depart) <= time + 1e-9)


def in_process_state(path: str) -> str:
    """The state libsumo loads for ``path``: ``path`` itself, or where it holds rail sub-driveways a copy
    without them (in a temporary folder removed at exit), which later starts in this process survive."""
    st = os.stat(path)
    key = (os.path.abspath(path), st.st_mtime_ns, st.st_size)
    if key in _copies:
        return _copies[key]
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rb") as f:
        text = f.read()
    if b"<subDriveWay " not in text:   # read once: a run starts scene after scene from one base state
        _copies[key] = path
        return path
    copy = os.path.join(_copy_folder(), f"{len(_copies)}_{os.path.basename(path)}")
    with opener(copy, "wb") as f:
        f.write(_SUB_DRIVE_WAY.sub(b"", text))
    _copies[key] = copy
    return copy


def _copy_folder() -> str:
    if not _folder:
        _folder.append(tempfile.mkdtemp(prefix="scendiff-states-"))
        atexit.register(shutil.rmtree, _folder[0], True)
    return _folder[0]


__all__ = ["in_process_state", "save_state", "waiting_in_state"]
