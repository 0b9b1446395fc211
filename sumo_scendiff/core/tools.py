"""Where SUMO's binaries and tools are: the ``eclipse-sumo`` wheel (no ``SUMO_HOME`` set-up)."""
from __future__ import annotations

import os


def sumo_home() -> str:
    import sumo  # the eclipse-sumo wheel
    return sumo.SUMO_HOME


def sumo_binary(name: str = "sumo") -> str:
    return os.path.join(sumo_home(), "bin", name)


def sumo_tool(*path: str) -> str:
    """A script of SUMO's ``tools/`` folder, e.g. ``sumo_tool("randomTrips.py")``."""
    return os.path.join(sumo_home(), "tools", *path)
