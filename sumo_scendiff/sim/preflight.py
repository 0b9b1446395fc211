"""The user's scenario loaded by stock SUMO before any expensive work: SUMO is the judge.

    scen = preflight(scenario_from_files(config="city.sumocfg"))   # ScenarioError: SUMO's own words

The ``sumo`` binary of the installed SUMO loads the scenario as its authors would run it (``-c``
their configuration, with the network, route and additional files the product uses), simulates
its first step (the first route chunk is read then) through TraCI and is closed: a missing file, a network that does not match the demand,
malformed XML, an option SUMO does not know come back as SUMO's first error, in one line naming
the file SUMO names, within seconds rather than after minutes of generation. Nothing is written
beside the user's files: every output option the configuration sets goes to SUMO's null device,
its additional files' outputs too (sim.additional), SUMO runs in a temporary folder. Its
``--end`` is not touched: a flow without an end departs until the simulation's end, and an earlier
end would make SUMO refuse flows that begin after it. A scenario SUMO takes longer than :data:`TIMEOUT_S` to load is not judged here
(the run loads it again and SUMO speaks then).
"""
from __future__ import annotations

import functools
import os
import re
import subprocess
import tempfile

from .additional import NULL, original, quiet_outputs
from .scenario import ScenarioError, SumoScenario
from .sumo import SILENT_OPTIONS, as_args

TIMEOUT_S = 60.0
# options that make SUMO do more than load: their values in the preflight
_SILENCED = {"save-state.times": "", "save-state.period": "-1"}
_OWN = ("remote-port", "num-clients")   # the preflight's TraCI connection
# options of another type than FILE that name an output file
_STR_OUTPUTS = ("device.ssm.file", "device.toc.file")
_AT = re.compile(r"At line/column (\d+)/(\d+)")


@functools.lru_cache(maxsize=None)
def option_table() -> dict[str, tuple[str, str]]:
    """The installed ``sumo``'s options, each name and synonym -> (its name, what the preflight
    sets it to when a configuration sets it: the null device for an output), from its template."""
    import xml.etree.ElementTree as ET

    from ..core.tools import sumo_binary
    with tempfile.TemporaryDirectory(prefix="scendiff-preflight-") as work:
        path = os.path.join(work, "template.sumocfg")
        try:
            subprocess.run([sumo_binary("sumo"), "--save-template", path], capture_output=True, timeout=60,
                           check=True)
            root = ET.parse(path).getroot()
        except (OSError, subprocess.SubprocessError, ET.ParseError):
            return {}
    out = {}
    for section in root:
        for opt in section:
            value = _silenced(section.tag, opt.tag, opt.get("type", ""))
            for name in [opt.tag] + (opt.get("synonymes") or "").split():
                out[name] = (opt.tag, value)
    return out


def _silenced(section: str, name: str, kind: str) -> str | None:
    if name in _SILENCED:
        return _SILENCED[name]
    if name in _STR_OUTPUTS or kind == "FILE" and (
            section in ("output", "report") and not name.endswith("input-file") or "output" in name):
        return NULL
    if kind == "FILE" and section == "configuration" and name != "configuration-file":
        return ""           # --save-configuration and the like write a file and stop
    return None


def quiet_flags(config: str) -> list[str]:
    """The command-line options that keep ``sumo -c config`` from writing or listening anywhere."""
    from sumolib.options import readOptions
    table, out = option_table(), []
    for opt in readOptions(config):
        name, value = table.get(opt.name, (opt.name, None))
        if value is not None and name not in _OWN:
            out += [f"--{name}", value]
    return out


def command(scen: SumoScenario) -> list[str]:
    """``sumo`` on ``scen`` as the run loads it, writing nothing (without its TraCI port)."""
    from ..core.tools import sumo_binary
    args = [sumo_binary("sumo")] + (["-c", scen.config] + quiet_flags(scen.config) if scen.config else [])
    args += ["-n", scen.net]
    if scen.routes:
        args += ["-r", ",".join(scen.routes)]
    if scen.additional:
        args += ["-a", ",".join(quiet_outputs(scen.additional))]
    return args + as_args(SILENT_OPTIONS)


def preflight(scen: SumoScenario, timeout: float = TIMEOUT_S) -> SumoScenario:
    """``scen`` once stock SUMO has loaded it and simulated its first step; raises
    :class:`ScenarioError` with SUMO's first error in one line (:func:`refusal`) when it refuses to."""
    from ..core.tools import sumo_home
    sumo_home()          # importing the wheel sets SUMO_HOME (and PROJ's data) as its `sumo` does
    with tempfile.TemporaryDirectory(prefix="scendiff-preflight-") as work:
        for _ in range(3):           # another process may take the free port first
            code, stderr = _first_step(command(scen), work, timeout)
            if code is None or "Address already in use" not in stderr:
                break
    if code:
        raise ScenarioError(refusal(scen, stderr, code))
    return scen


def _first_step(args: list[str], work: str, timeout: float) -> tuple[int | None, str]:
    """SUMO's exit code (0: it loaded and stepped; None: not done within ``timeout``) and stderr."""
    import time

    from sumolib.miscutils import getFreeSocketPort
    from traci.connection import Connection
    port = getFreeSocketPort()
    with open(os.path.join(work, "stderr.txt"), "w+", errors="replace") as err:
        proc = subprocess.Popen(args + ["--remote-port", str(port), "--num-clients", "1"], cwd=work,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
        deadline, conn = time.monotonic() + timeout, None
        try:
            while conn is None and proc.poll() is None and time.monotonic() < deadline:
                try:
                    conn = Connection("localhost", port, proc, None, False)
                except OSError:
                    time.sleep(0.05)      # SUMO is still loading the network and additional files
            if conn is not None:
                conn.simulationStep()
                conn.close()
        except Exception:                 # traci's FatalTraCIError: SUMO stopped, stderr says why
            pass
        finally:
            try:
                code = proc.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                code = None
        err.seek(0)
        return code, err.read()


def refusal(scen: SumoScenario, stderr: str, code: int = 1) -> str:
    """SUMO's first error in ``stderr`` in one line: the file it names (the user's, not a quiet
    copy) with the line and column, or the scenario's files, then SUMO's message."""
    from ..core.sumo_log import first_error
    message = first_error(stderr)
    if message is None:
        tail = [ln.strip() for ln in stderr.splitlines() if ln.strip()][-1:] or [f"exit code {code}"]
        message = f"stopped while loading ({tail[0]})"
    lines = stderr.splitlines()
    start = next((k for k, ln in enumerate(lines) if ln.startswith("Error:")), len(lines))
    more = []
    for ln in lines[start + 1:]:
        if not ln.startswith(" "):
            break
        more.append(ln.strip())
    named = next((m.group(1) for m in map(re.compile(r"In file '(.*)'").match, more) if m), None)
    at = next((m for m in map(_AT.match, more) if m), None)
    rest = " ".join(m for m in more if not m.startswith(("In file '", "At line/column")))
    text = " ".join(p for p in (message, rest) if p)
    if named:
        return f"{original(named)}: " + (f"line {at.group(1)}, column {at.group(2)}: " if at else "") + \
            f"SUMO refuses it: {text}"
    who = scen.config or ", ".join((scen.net,) + scen.routes + scen.additional)
    return f"{who}: SUMO refuses to load it: {text}"


__all__ = ["TIMEOUT_S", "command", "option_table", "preflight", "quiet_flags", "refusal"]
