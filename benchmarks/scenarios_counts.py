"""The corpus's replay counts (benchmarks/scenarios.py): what SUMO holds at a replay's first step (its
summary-output) against what the exported folder says it holds -- stock SUMO's vehicles at the scene's time
plus the seeded agents, the fill's agents plus the demand's departures due then (docs/corpus.md, Steps)."""
from __future__ import annotations

import gzip
import json
import os
import signal
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

from scenarios_features import _binary

# the replays and the step whose folder each replays
NEEDS = {"run_replay": "run", "fill_replay": "fill", "fill_start": "fill"}
REFERENCE_TIMEOUT = 600   # s: a stock SUMO run of a configuration (the corpus's first step, a count's reference)


class CountError(RuntimeError):
    """A replay's count cannot be made (one line): the step fails saying so, never passes uncounted."""


def _sumo() -> str:
    return _binary("sumo")


def _config_value(cfg: Path, key: str) -> str | None:
    """A configuration's option ``key`` (its long name) by whichever of SUMO's names it is written."""
    from sumo_scendiff.core.sumo_xml import option_name
    for el in ET.parse(cfg).getroot().iter():
        if isinstance(el.tag, str) and option_name(el.tag) == key and el.get("value") is not None:
            return el.get("value")
    return None


def summary_steps(summary: Path):
    """The <step> elements of a SUMO summary-output, as dicts of their attributes, in time order."""
    if summary.is_file():
        for _, el in ET.iterparse(summary):
            if el.tag == "step":
                yield dict(el.attrib)
            el.clear()


def step_at(summary: Path, t: float) -> dict | None:
    """The summary's last step at or before ``t``."""
    last = None
    for st in summary_steps(summary):
        if float(st["time"]) > t + 1e-6:
            break
        last = st
    return last


def running_at(summary: Path, t: float) -> int | None:
    """Vehicles on the road in stock SUMO's run at T (its summary-output): how much traffic the product
    was given to fill around."""
    st = step_at(summary, t)
    return int(st["running"]) if st else None


def held(st: dict | None) -> int | None:
    """The vehicles SUMO holds at a step: on the road (running) and loaded, due, not yet inserted
    (waiting: the portable start's vehicles still queued at their departure)."""
    return int(st["running"]) + int(st["waiting"]) if st else None


# a replay's first step may differ from what the folder says by this much (docs/corpus.md: vehicles
# arriving or teleported in the first step, the demand's departures due in it)
COUNT_TOLERANCE = (2, 0.02)     # vehicles, share of the expected count: the larger of the two


def _seeded(doc: dict) -> int:
    """The agents a scene.json / fill.json says stand in SUMO: placed, or seeded off their pose."""
    return sum(a.get("status") in ("placed", "misplaced") for a in doc.get("agents", []))


def expected_vehicles(name: str, out: Path) -> tuple[int, str]:
    """What a replay must hold at its first step and the words naming where that count comes from:
    for the run's scene, stock SUMO's vehicles at the scene's time plus the scene's seeded agents; for
    the fill's state and portable start, fill.json's seeded agents (the demand's own among them), and
    for the state the vehicles it holds waiting to enter (fill.json's ``waiting_to_enter``). Raises
    CountError where it cannot be counted."""
    if name == "run_replay":
        doc_path = out / "run" / "scene_000" / "scene.json"
        if not doc_path.is_file():
            raise CountError("could not count: the run wrote no scene_000/scene.json")
        doc = json.loads(doc_path.read_text())
        t, seed = float(doc["time"]), doc["sumo_options"].get("seed")
        stock = held(step_at(_stock_summary(out, t, seed), t))
        if stock is None:
            raise CountError(f"could not count: stock SUMO's reference run has no step at {t:g} s")
        return stock + _seeded(doc), f"stock SUMO (seed {seed}) held {stock} at {t:g} s + {_seeded(doc)} placed"
    doc_path = out / "fill" / "fill.json"
    if not doc_path.is_file():
        raise CountError("could not count: the fill wrote no fill.json")
    doc = json.loads(doc_path.read_text())
    seeded = _seeded(doc)
    # the state keeps SUMO's queue of vehicles due but not yet in (a full network's), the portable start not:
    # SUMO loads each into its insertion queue and tries it in the first step, where it enters or waits on,
    # held either way (MSStateHandler::closeVehicle, MSInsertionControl::emitVehicles)
    queued = int((doc.get("density") or {}).get("waiting_to_enter") or 0) if name == "fill_replay" else 0
    due, left = _first_step(name, out, doc)
    return seeded + due + queued - left, (
        f"fill.json placed {seeded}" + (f" + {due} the demand departs then" if due else "")
        + (f" + {queued} waiting to enter in its state" if queued else "")
        + (f" - {left} arriving in its first step" if left else ""))


def _first_step(name: str, out: Path, doc: dict) -> tuple[int, int]:
    """What a fill replay's first step adds to the vehicles its folder holds and takes from them, both
    replays counted alike: SUMO started on the replay's configuration in the fill's folder for one step
    (by TraCI), the vehicles it holds then (on the road or waiting to enter) that the folder's own do
    not include, and those of the folder's own arriving in it (the summary's first step is counted
    after it). The folder's own: the state's vehicles, or the portable start's file's
    (:func:`_own_vehicles`). What it adds is the demand's departures then, flows the fill numbers on
    included (a route file's vehicles due then are in the state's queue already, sumorl_nguyen; a flow
    ending at T makes its last vehicle at T, ma2c_real_net, which a run begun at T without the state
    does not); what it takes off, the state's cars at their arrival (feat_distributions: three). (0, 0)
    without the configuration."""
    import uuid

    import traci
    from sumolib.miscutils import getFreeSocketPort
    cfg = out / "fill" / ("scenario.sumocfg" if name == "fill_replay" else "start.sumocfg")
    own = _own_vehicles(name, out, doc)
    if not cfg.is_file() or own is None:
        return 0, 0
    # SUMO started in the fill's folder, as the replay step: the scenario's outputs land there
    port = getFreeSocketPort()
    proc = subprocess.Popen([_sumo(), "-c", str(cfg), "--no-step-log", "true", "--remote-port", str(port)],
                            cwd=cfg.parent, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    label = f"corpus-{uuid.uuid4().hex}"
    try:
        conn = traci.connect(port, label=label, proc=proc)
        conn.simulationStep()
        now = set(conn.vehicle.getIDList()) | set(conn.simulation.getPendingVehicles())
        left = len(set(conn.simulation.getArrivedIDList()) & own)
        conn.close()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    return len(now - own), left


def _own_vehicles(name: str, out: Path, doc: dict) -> set[str] | None:
    """The vehicle ids a fill replay starts with: the state's (state.xml.gz) or the portable start's
    own file's (fill.json's ``portable_ids``: ``start.<vehicle> in start.rou.xml``; start.rou.xml where
    it names none); None where that file is not there."""
    import re
    if name == "fill_replay":
        state = out / "fill" / "state.xml.gz"
        if not state.is_file():
            return None
        with gzip.open(state, "rt") as f:
            return set(re.findall(r'<vehicle id="([^"]*)"', f.read()))
    start = out / "fill" / ((doc.get("portable_ids") or "").rpartition(" in ")[2] or "start.rou.xml")
    if not start.is_file():
        return None
    return {el.get("id") for _, el in ET.iterparse(start) if el.tag == "vehicle"}


def _stock_summary(out: Path, t: float, seed) -> Path:
    """Stock SUMO's summary-output of the run's configuration up to ``t`` with the product's SUMO seed:
    the vehicles the scene kept from the simulation are those of a run with that seed (the corpus's own
    stock step keeps the configuration's, SUMO's default where it names none). Without a TraCI server
    (``remote-port 0``), as the product's own SUMO: one the configuration asks for waits for a client
    until the time limit (sumorl_ow), and its binary outlived the killed wrapper, holding the port."""
    cfg = json.loads((out / "run" / "run.json").read_text())["configuration"]
    path = out / "run_reference_summary.xml"
    path.unlink(missing_ok=True)    # an earlier run's summary is not this one's count
    # a configuration's output-prefix (MoST's "most.") would rename the summary read here
    cmd = [_sumo(), "-c", cfg, "--end", f"{t:g}", "--no-step-log", "true", "--summary-output", path,
           "--output-prefix", "", "--remote-port", "0", *(["--seed", str(seed)] if seed is not None else [])]
    # its own process group: the `sumo` wrapper's binary is ended with it at the time limit
    proc = subprocess.Popen([str(c) for c in cmd], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=out,
                            start_new_session=True)
    try:
        proc.wait(timeout=REFERENCE_TIMEOUT)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        raise CountError(f"could not count: stock SUMO's reference run took over {REFERENCE_TIMEOUT} s") from None
    if not path.is_file():
        raise CountError(f"could not count: stock SUMO's reference run wrote no {path.name}")
    return path


def check_count(name: str, res: dict, out: Path) -> dict:
    """``res`` of a replay with SUMO's vehicles at its first step against what the folder holds
    (:func:`expected_vehicles`): a mismatch beyond :data:`COUNT_TOLERANCE` fails the step."""
    if name not in NEEDS or not res.get("ok"):
        return res
    try:
        want, source = expected_vehicles(name, out)
    except CountError as e:
        return {**res, "ok": False, "error": str(e)}
    got = held(next(summary_steps(out / f"{name}_summary.xml"), None))
    if got is None:
        return {**res, "ok": False, "error": f"could not count: {name}_summary.xml has no step"}
    res = {**res, "vehicles": {"sumo": got, "expected": want}}
    if abs(got - want) > max(COUNT_TOLERANCE[0], COUNT_TOLERANCE[1] * want):
        what = "scene" if name == "run_replay" else ("state" if name == "fill_replay" else "start")
        res.update(ok=False, error=f"{what} holds {got} vehicles, {source}")
    return res
