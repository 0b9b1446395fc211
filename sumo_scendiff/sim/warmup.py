"""The user's demand run up to a time at SUMO's own speed, its state kept for the next time.

    sim = start(cfg)                         # the scenario's step length and options (sim.sumo)
    warm_up(sim, 900.0, cfg)                 # one simulationStep(900): no Python between steps
    sim = start_warm(cfg, 900.0)             # the same, from ~/.cache/sumo-scendiff/states when there
    path = warm_state(cfg, 900.0)            # that state alone: start(replace(cfg, state=path))

Running a demand to a time is what stock ``sumo -c scenario.sumocfg --end T`` does; here it is
``simulationStep(T)``, one call into SUMO, so it costs what SUMO costs. The state at T is saved under
:func:`state_dir`, named by a key of everything that decides it (the SUMO version, the options, the
contents of every input file, the start and T): asked again for the same scenario and time, SUMO starts
from that state (``--load-state``) instead of running the demand again. A changed file gives a new key.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import replace

from ..core.files import file_sha256
from ..core.sumo_xml import option_name
from .state import save_state

# bumped when what a cached state holds changes (its options, how it is saved)
STATE_VERSION = 2
# options naming an input file (by any of their names, core.sumo_xml.option_name): their contents, not
# their paths, are the key
FILE_OPTIONS = frozenset({"net-file", "route-files", "additional-files"})
# SUMO saves its random number generators with a state only when asked: without them a run started
# from the state draws other numbers than the run that saved it (other departures of a flow with a
# probability, other driver imperfection) -- an option on what a state holds, not on what SUMO simulates
RNG = ("--save-state.rng", "true")


class WarmUpError(RuntimeError):
    """The demand cannot be run to the time asked (one line)."""


def state_dir() -> str:
    """Where saved warm-up states are kept (core.files.cache_dir)."""
    from ..core.files import cache_dir as project_cache
    return project_cache("states")


def warm_config(cfg, rng: bool = True):
    """``cfg`` as a warm-up runs it: the scenario as stock SUMO runs it (its own step length and
    options, without the options the seeding adds: they are the seeding's, and checking collisions
    inside junctions costs SUMO much of its time on a city), its state saved to the seeding's precision
    (SUMO's default, cm, moves a vehicle), and with ``rng`` saving SUMO's random number generators."""
    from .sumo import ADDED_OPTIONS
    precision = ("save-state.precision", ADDED_OPTIONS["save-state.precision"])
    return replace(cfg, extra=_without_rng(cfg.extra) + (RNG if rng else ()), seeding_options=False,
                   scenario_options=(*cfg.scenario_options, precision))


def _without_rng(extra) -> tuple:
    """``extra`` (a command line's words) without the option :data:`RNG` and its value."""
    out, skip = [], False
    for a in extra:
        if not skip and a == RNG[0]:
            skip = True
            continue
        if not skip:
            out.append(a)
        skip = False
    return tuple(out)


def state_key(cfg, until: float) -> str:
    """The key of ``cfg`` (sim.sumo.SimConfig) run to ``until``: SUMO's version, its command line (its
    seed and options on random numbers among them) with each input file replaced by its contents' hash
    (:func:`_contents_key`), and the time."""
    args, out = replace(cfg, extra=_without_rng(cfg.extra)).args(), []
    for k, a in enumerate(args):
        if k and option_name(args[k - 1].lstrip("-")) in FILE_OPTIONS:
            a = ",".join(_contents_key(p) for p in a.split(","))
        out.append(a)
    doc = {"version": STATE_VERSION, "sumo": _sumo_version(), "args": out,
           "until": round(float(until), 6)}
    return hashlib.sha256(json.dumps(doc).encode()).hexdigest()[:24]


def _contents_key(path: str, chain: tuple[str, ...] = ()) -> str:
    """The hash of input file ``path``'s bytes and of every file it ``<include>``s (SUMO reads them in
    place: an edited included file is other traffic)."""
    digest = file_sha256(path)
    hrefs = _includes(path) if path not in chain else []
    if not hrefs:
        return digest
    parts = [digest, *(_contents_key(h, chain + (path,)) if os.path.isfile(h) else "absent:" + h for h in hrefs)]
    return hashlib.sha256("|".join(parts).encode()).hexdigest()


def _includes(path: str) -> list[str]:
    """The files ``path`` names in ``<include href>``, as SUMO resolves them; read in a stream only where
    its text holds ``<include`` at all (a city's route file is large)."""
    from ..core.sumo_xml import XmlError, include_path, open_xml
    try:
        with open_xml(path) as f:
            tail, seen = b"", False
            for chunk in iter(lambda: f.read(1 << 20), b""):
                if b"<include" in tail + chunk:
                    seen = True
                    break
                tail = chunk[-8:]
            if not seen:
                return []
            f.seek(0)
            hrefs = []
            for _, el in ET.iterparse(f):
                if el.tag == "include" and el.get("href"):
                    hrefs.append(include_path(path, el.get("href")))
                el.clear()
            return hrefs
    except (XmlError, ET.ParseError, OSError):     # SUMO says what is wrong with it when it loads it
        return []


def _sumo_version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("libsumo")
    except PackageNotFoundError:    # SUMO from a SUMO_HOME of its own: its binary says
        import subprocess

        from ..core.tools import sumo_binary
        return subprocess.run([sumo_binary("sumo"), "--version"], capture_output=True, text=True).stdout[:40]


def cached_state(cfg, until: float, folder: str | None = None) -> str | None:
    """The saved state of ``cfg`` at ``until`` if one was kept, else None."""
    path = os.path.join(folder or state_dir(), f"{state_key(cfg, until)}.xml.gz")
    return path if os.path.isfile(path) else None


def warm_up(sim, until: float, cfg=None, folder: str | None = None) -> str | None:
    """Run ``sim`` (SUMO started on :func:`warm_config` of ``cfg``) to ``until`` in one call; with
    ``cfg`` the state at ``until`` is saved under ``folder`` (default :func:`state_dir`) for :func:`start_warm`. Returns
    that state's path (None without ``cfg``). Raises WarmUpError if ``until`` lies before now."""
    now = sim.simulation.getTime()
    if until < now - 1e-9:
        raise WarmUpError(f"--begin {until:g}: the simulation is already at {now:g} s")
    if until > now:
        sim.simulationStep(until)
    return None if cfg is None else save(sim, cfg, until, folder)


def save(sim, cfg, until: float, folder: str | None = None) -> str:
    """The state of ``sim`` (``cfg`` at ``until``) saved as its key's file; written beside and renamed,
    so that a state that is there is whole."""
    folder = folder or state_dir()
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, f"{state_key(cfg, until)}.xml.gz")
    fd, tmp = tempfile.mkstemp(suffix=".xml.gz", prefix=".partial-", dir=folder)
    os.close(fd)
    try:
        os.replace(save_state(sim, tmp), path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def warm_state(cfg, until: float, folder: str | None = None, quiet: bool = True) -> str:
    """The saved state of ``cfg`` run to ``until`` (:func:`warm_config`: as stock SUMO runs it): the
    one kept from an earlier call, else made now by :func:`warm_up` (SUMO started, run, closed).
    Start SUMO from it with ``replace(cfg, state=path)``."""
    from .sumo import close, start
    warming = warm_config(cfg)
    path = cached_state(warming, until, folder)
    if path is None:
        sim = start(warming, quiet=quiet)
        try:
            path = warm_up(sim, until, warming, folder)
        finally:
            close(sim)
    return path


def start_warm(cfg, until: float, folder: str | None = None, quiet: bool = True, cache: bool = True):
    """SUMO on ``cfg`` at ``until``, started from :func:`warm_state` (``--load-state``). Both ways, the
    state kept or made now, the simulation goes on from the same state file, so asking again gives
    the same run (a run that saved a state and a run started from it differ: vehicles still to
    depart draw their numbers in another order). Without ``cache`` the demand is run to ``until``
    and that simulation returned, nothing saved. Returns the simulation."""
    from .sumo import start
    if not cache:
        sim = start(cfg, quiet=quiet)
        warm_up(sim, until)
        return sim
    return start(replace(cfg, state=warm_state(cfg, until, folder, quiet)), quiet=quiet)


__all__ = ["WarmUpError", "cached_state", "save", "start_warm", "state_dir", "state_key", "warm_config", "warm_state",
           "warm_up"]
