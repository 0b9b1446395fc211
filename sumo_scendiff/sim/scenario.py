"""A user's SUMO scenario as its authors ship it: a ``.sumocfg`` (network, route files, additional
files with vTypes, TLS programs, detectors, stops; begin and end), or ``-n``/``-r``/``-a`` given
directly, or both (the flags replace what the configuration names).

    scen = scenario_from_files(config="cologne3.sumocfg")
    scen = scenario_from_files(net="city.net.xml", routes=["a.rou.xml"], additional=["vtypes.add.xml"])
    scen = preflight(scen)      # sim.preflight: stock SUMO loads it first, its refusal in one line

The configuration is read with sumolib (``sumolib.options.readOptions``); paths in it are relative to
its folder and file lists are comma-separated, as SUMO reads them; its times are SUMO's (seconds or
H:M:S, core.sumo_xml.seconds). The inputs and the time window are taken, and the options that say
how SUMO runs the demand (``processing``, ``routing``, devices, ...: ``--junction-taz``, rerouting,
teleporting) are carried into every SUMO run and exported configuration; outputs a configuration
names (tripinfo, logs, ...) are the user's business, never written beside their files, and reports,
the GUI's settings and the seed are the product's.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

# option names of a .sumocfg (long: core.sumo_xml.option_name reads the others) -> SumoScenario fields
_LISTS = {"route-files": "routes", "additional-files": "additional"}
_FILES = {"net-file": "net"}
_TIMES = {"begin": "begin", "end": "end"}
# sections of a .sumocfg whose options are not carried (see the module's doc); an option outside any
# section is carried unless it names a file or an output. The mesoscopic model (its section's options:
# mesosim, meso-edgelength, ...) is carried; the fill alone leaves it out (sim.sumo.settings, meso_notice)
_NOT_CARRIED = frozenset({"input", "output", "time", "report", "gui_only", "traci_server", "random_number"})
# the sections an option given outside any section is left out by (an input option such as
# junction-taz, which names no file, is carried wherever it is given)
_NOT_CARRIED_LOOSE = _NOT_CARRIED - {"input", "output"}


# SUMO's --seed where a configuration gives none (``sumo --help``: "Use INT as random seed [23423]")
SUMO_DEFAULT_SEED = 23423


class ScenarioError(ValueError):
    """One line: the file (or flag) and the problem."""


@dataclass(frozen=True)
class SumoScenario:
    net: str
    routes: tuple[str, ...] = ()
    additional: tuple[str, ...] = ()
    begin: float | None = None       # the configuration's <begin> (s)
    end: float | None = None
    step_length: float | None = None  # the configuration's <step-length> (s)
    config: str | None = None        # the .sumocfg it came from
    options: tuple[tuple[str, str], ...] = ()   # its options on how SUMO runs the demand (name, value)


def _split(value: str) -> list[str]:
    """A file list option's files as SUMO reads them: comma-separated, each trimmed and
    URL-decoded (SUMO writes a space in a file name as %20); a space does not separate files."""
    from urllib.parse import unquote
    return [unquote(v.strip()) for v in value.split(",") if v.strip()]


def _time(path: str, name: str, value: str) -> float:
    from ..core.sumo_xml import seconds
    t = seconds(value)
    if t is None:
        raise ScenarioError(f"{path}: {name}: not a time SUMO reads (seconds or H:M:S, got {value!r})")
    return t


def add_input_arguments(p, config: str, routes: str, additional: str) -> None:
    """SUMO's own input flags on a CLI's parser (-c, -n, -r, -a, as sumo names them), each with its
    help in this CLI's terms; :func:`input_flags_problem` checks the -n/-c pair once parsed."""
    p.add_argument("-c", "--configuration-file", dest="config", metavar="FILE", help=config)
    p.add_argument("-n", "--net-file", "--net", dest="net", help="SUMO network (.net.xml[.gz])")
    p.add_argument("-r", "--route-files", "--routes", dest="routes", default=None, help=routes)
    p.add_argument("-a", "--additional-files", dest="additional", default=None, help=additional)


def is_network_name(path: str) -> bool:
    """Whether a file's name is a SUMO network's (``.net.xml``, gzipped or not). A configuration may have
    any name (stock SUMO reads ``-c erlangen.sumo.cfg`` as Veins ships it), so a -c is refused only
    where its name says it is a network."""
    return path.endswith((".net.xml", ".net.xml.gz"))


def input_flags_problem(net: str | None, config: str | None) -> str | None:
    """What is wrong with a CLI's -n/-c pair before any file is read (one line), or None."""
    if not (net or config):
        return "one of -n/--net-file or -c/--configuration-file is required"
    if net and net.endswith(".sumocfg"):
        return f"-n: {net}: a SUMO configuration, not a network (give it with -c)"
    if config and is_network_name(config):
        return f"-c: {config}: a SUMO network, not a configuration (a network goes to -n)"
    return None


RUN_FLAGS = "-n/-r/-a"   # what replaces a configuration's files on run's and the fill's command line


def read_sumocfg(path: str, skip: frozenset[str] = frozenset(), replace_with: str = RUN_FLAGS) -> dict:
    """The inputs and time window of a ``.sumocfg`` as a dict of SumoScenario fields, paths resolved
    against its folder; a file it names that does not exist is an error naming both and how to give
    another (``replace_with``). Options named in ``skip`` (those a flag replaces) are not read."""
    import xml.sax

    from sumolib.options import readOptions
    if not os.path.isfile(path):
        raise ScenarioError(f"{path}: no such file")
    try:
        opts = readOptions(path)
    except (xml.sax.SAXException, UnicodeDecodeError) as e:
        raise ScenarioError(f"{path}: not a SUMO configuration ({str(e).splitlines()[0]})") from None
    if not opts:
        raise ScenarioError(f"{path}: not a SUMO configuration (no options with a value)")
    from ..core.sumo_xml import option_name
    here = os.path.dirname(os.path.abspath(path))
    out: dict = {"config": os.path.abspath(path)}
    for opt in opts:
        name = option_name(opt.name)
        if name in skip:
            continue
        if name in _FILES or name in _LISTS:
            given = _split(opt.value)
            files = [os.path.normpath(os.path.join(here, f)) for f in given]
            for f, g in zip(files, given):
                if not os.path.exists(f):
                    raise ScenarioError(f"{path}: {opt.name}: {g}: no such file (give {replace_with} to use "
                                        "other files)")
            if name in _FILES:
                if not files:
                    raise ScenarioError(f"{path}: {opt.name}: names no file")
                out["net"] = files[0]
            else:
                out[_LISTS[name]] = tuple(files)
        elif name in _TIMES:
            out[_TIMES[name]] = _time(path, opt.name, opt.value)
        elif name == "step-length":
            out["step_length"] = _time(path, opt.name, opt.value)
            if not out["step_length"] > 0:
                raise ScenarioError(f"{path}: step-length: must be > 0 ({opt.value!r})")
    out["options"] = run_options(path)
    return out


def run_options(path: str) -> tuple[tuple[str, str], ...]:
    """The options of a ``.sumocfg`` on how SUMO runs its demand, as (name, value): those of every
    section but inputs, outputs, the time window, reports, the GUI's, TraCI's and the seed, and none
    that names a file (its path would not travel with the exported scenario)."""
    import xml.etree.ElementTree as ET

    from ..core.sumo_xml import option_name
    from ..core.tools import sumo_option_sections
    sections = sumo_option_sections()
    out = []
    for section in ET.parse(path).getroot():
        if not isinstance(section.tag, str):          # a comment
            continue
        opts = [section] if section.get("value") is not None else list(section)
        if section.get("value") is None and section.tag in _NOT_CARRIED:
            # how strictly SUMO reads the files (a report option) decides whether it loads them at all
            out += [(o.tag, o.get("value")) for o in section if isinstance(o.tag, str)
                    and o.tag.startswith("xml-validation") and o.get("value") is not None]
            continue
        for opt in opts:
            name, value = option_name(opt.tag) if isinstance(opt.tag, str) else opt.tag, opt.get("value")
            # an option outside any section (SUMO reads those too) goes by the section SUMO files it
            # under: a TraCI port given so would make every in-process run wait for a client
            if (not isinstance(name, str) or value is None or name in _LISTS or name in _FILES or name in _TIMES
                    or (opt is section and sections.get(name) in _NOT_CARRIED_LOOSE
                        and not name.startswith("xml-validation"))
                    or "output" in name or name.endswith(("-file", "-files", "-log", ".file"))):
                continue
            out.append((name, value))
    return tuple(out)


def meso_notice(config: str | None, fill: bool = False) -> str | None:
    """The warning for a configuration that runs SUMO's mesoscopic model (``mesosim``; None for any
    other): ``run`` and ``sweep`` carry it, and a mesoscopic vehicle stands in a segment of its edge, not
    at a pose; the fill (``fill``) seeds microscopically, its portable start runs the model (docs/sumo-options.md)."""
    import xml.etree.ElementTree as ET

    from ..core.sumo_xml import boolean
    if not config or not os.path.isfile(config):
        return None
    try:
        meso = any(boolean(el.get("value")) for el in ET.parse(config).getroot().iter("mesosim"))
    except (ET.ParseError, ValueError):
        return None                   # read_sumocfg names what is wrong with it
    if not meso:
        return None
    if fill:
        return (f"{config}: mesosim: the fill seeds and saves its state microscopically (it places vehicles at "
                "lane positions, which SUMO's mesoscopic model does not have, and that model loads no "
                "microscopic state): scenario.sumocfg is microscopic, start.sumocfg runs the mesoscopic model")
    return (f"{config}: mesosim: the scenes run in SUMO's mesoscopic model, as configured: a vehicle there "
            "stands in a segment of its edge, not at its pose (scene.json: placed = in its pose's edge)")


def scenario_from_files(config: str | None = None, net: str | None = None,
                        routes: Sequence[str] = (), additional: Sequence[str] = (),
                        replace_with: str = RUN_FLAGS) -> SumoScenario:
    """The scenario of a ``.sumocfg`` with ``-n``/``-r``/``-a`` replacing what it names, so a
    configuration naming a file that was not shipped is usable with the flag that replaces it
    (``replace_with``: how the caller's user gives them, for the error)."""
    skip = {name for name, flag in (("net-file", net), ("route-files", routes), ("additional-files", additional))
            if flag}
    fields = read_sumocfg(config, frozenset(skip), replace_with) if config else {}
    if net:
        fields["net"] = os.path.abspath(net)
    if routes:
        fields["routes"] = tuple(os.path.abspath(r) for r in routes)
    if additional:
        fields["additional"] = tuple(os.path.abspath(a) for a in additional)
    if not fields.get("net"):
        raise ScenarioError(f"{config}: names no net-file (give -n)" if config else
                            "-n/--net-file or -c/--configuration-file is required")
    for flag, files in (("-n", (fields["net"],)), ("-r", fields.get("routes", ())),
                        ("-a", fields.get("additional", ()))):
        for f in files:
            if not os.path.exists(f):
                raise ScenarioError(f"{flag}: {f}: no such file")
    if fields["net"].endswith(".sumocfg"):
        raise ScenarioError(f"-n: {fields['net']}: a SUMO configuration, not a network (give it with -c)")
    return SumoScenario(**fields)


def own_random(scen: SumoScenario) -> tuple[int, tuple[str, ...]]:
    """The seed the user's own ``sumo -c`` runs ``scen`` with (its configuration's ``seed``, else SUMO's
    default) and its other options on SUMO's random numbers (``random``, ``thread-rngs``: the section
    ``random_number``, which :attr:`SumoScenario.options` leaves out) as command-line words. A demand run
    to the seeding time is the user's own run: the CLIs' ``-s`` seeds the model's draws only, never the
    demand's departures, lanes, speed factors or routes."""
    from sumolib.options import readOptions

    from ..core.sumo_xml import option_name
    from ..core.tools import sumo_option_sections
    if not scen.config:
        return SUMO_DEFAULT_SEED, ()
    sections, seed, extra = sumo_option_sections(), SUMO_DEFAULT_SEED, ()
    for opt in readOptions(scen.config):
        name = option_name(opt.name)
        if sections.get(name) != "random_number":
            continue
        if name == "seed":
            seed = int(opt.value)
        else:
            extra += (f"--{name}", opt.value)
    return seed, extra
