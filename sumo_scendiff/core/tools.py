"""Where SUMO's binaries and tools are: the ``eclipse-sumo`` wheel (no ``SUMO_HOME`` set-up)."""
from __future__ import annotations

import functools
import os


def sumo_home() -> str:
    import sumo  # the eclipse-sumo wheel
    return sumo.SUMO_HOME


def sumo_binary(name: str = "sumo") -> str:
    return os.path.join(sumo_home(), "bin", name)


def sumo_tool(*path: str) -> str:
    """A script of SUMO's ``tools/`` folder, e.g. ``sumo_tool("randomTrips.py")``."""
    return os.path.join(sumo_home(), "tools", *path)


@functools.lru_cache(maxsize=None)
def _sumo_template() -> tuple[tuple[str, str, str], ...]:
    """The installed ``sumo``'s options as (section, name, default) from its configuration template;
    empty where it cannot write one (the callers' own fallbacks; SUMO itself will say what is wrong)."""
    import subprocess
    import tempfile
    import xml.etree.ElementTree as ET
    with tempfile.TemporaryDirectory(prefix="scendiff-template-") as work:
        path = os.path.join(work, "template.sumocfg")
        try:
            subprocess.run([sumo_binary("sumo"), "--save-template", path], capture_output=True, timeout=60, check=True)
            return tuple((section.tag, opt.tag, opt.get("value", ""))
                         for section in ET.parse(path).getroot() for opt in section)
        except (OSError, subprocess.SubprocessError, ET.ParseError):
            return ()


def sumo_defaults() -> dict[str, str]:
    """The installed ``sumo``'s option defaults (name -> value), from its configuration template:
    they change between SUMO versions (``default.departspeed`` was 0 and is "avg" in 1.28)."""
    return {name: value for _, name, value in _sumo_template()}


def sumo_option_sections() -> dict[str, str]:
    """The installed ``sumo``'s options (name -> the section of its configuration they belong to:
    ``traci_server``, ``gui_only``, ``processing``, ...), for options a configuration gives outside
    any section."""
    return {name: section for section, name, _ in _sumo_template()}
