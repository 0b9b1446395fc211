"""Running the corpus (benchmarks/scenarios.py): one scenario's six steps beside stock SUMO, and the table of
the results (markdown and JSON); what each replay must hold is scenarios_counts.py's."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from scenarios_build import build
from scenarios_counts import NEEDS, REFERENCE_TIMEOUT, _config_value, _sumo, check_count, running_at
from scenarios_registry import REGISTRY, Scenario

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = Path.home() / ".cache" / "sumo-scendiff" / "corpus"
MIN_AREA_WIDTH = 10.0   # m: an area clipped narrower than a road is the square's extent there
AREA_SIDE = 400.0      # m: the fill's square when the registry names no area
ROLL = 30.0            # s: how far past T stock SUMO runs each configuration
TIMEOUT = {"sumo": REFERENCE_TIMEOUT, "run": 1200, "run_replay": 300, "fill": 1500, "fill_replay": 600,
           "fill_start": 600}


def begin_time(sc: Scenario, cfg: Path) -> float:
    """T: the registry's, else the configuration's begin (SUMO's clock format allowed) + offset."""
    if sc.begin is not None:
        return sc.begin
    from sumolib.miscutils import parseTime
    return parseTime(_config_value(cfg, "begin") or "0") + sc.offset


def net_boundary(net: Path) -> tuple:
    """The network's convBoundary (read from its <location>, without loading the network)."""
    from sumolib import openz
    with openz(str(net)) as f:
        for _, el in ET.iterparse(f):
            if el.tag == "location":
                return tuple(float(v) for v in el.get("convBoundary").split(","))
    raise ValueError(f"{net}: no <location> element")


def car_centre(net: Path, half: float = AREA_SIDE / 2) -> tuple | None:
    """The median of the car edges' junction positions (inside the network's streets: a rail or
    pedestrian fringe can move a bounding box's centre off every car lane) and False; where the square of
    half side ``half`` about it holds no car lane (a loop, a grid of long blocks), the car junction nearest
    it and True."""
    import math
    import statistics

    import sumolib
    from shapely.geometry import LineString, box
    edges = [e for e in sumolib.net.readNet(str(net)).getEdges(withInternal=False) if e.allows("passenger")]
    if not edges:
        return None
    nodes = [node.getCoord() for e in edges for node in (e.getFromNode(), e.getToNode())]
    cx, cy = statistics.median(x for x, _ in nodes), statistics.median(y for _, y in nodes)
    square = box(cx - half, cy - half, cx + half, cy + half)
    if any(square.intersects(LineString(e.getShape())) for e in edges):
        return (cx, cy), False
    return min(nodes, key=lambda p: math.hypot(p[0] - cx, p[1] - cy)), True


def fill_area(sc: Scenario, cfg: Path, side: float = AREA_SIDE) -> tuple:
    """The registry's area, else a square of ``side`` about :func:`car_centre`, inside the network's
    boundary unless it is about a junction (a corner's lanes lie beyond the boundary's line)."""
    if sc.area is not None:
        return sc.area
    net = cfg.parent / _config_value(cfg, "net-file")
    x0, y0, x1, y1 = net_boundary(net)
    h = side / 2
    (cx, cy), at_junction = car_centre(net, h) or (((x0 + x1) / 2, (y0 + y1) / 2), False)
    if at_junction:
        return (cx - h, cy - h, cx + h, cy + h)
    (ax0, ax1), (ay0, ay1) = _clip(cx - h, cx + h, x0, x1), _clip(cy - h, cy + h, y0, y1)
    return (ax0, ay0, ax1, ay1)


def _clip(lo: float, hi: float, b0: float, b1: float) -> tuple:
    """[lo, hi] inside the boundary's [b0, b1], unless that leaves no width: a straight road's boundary
    is a line (its lanes lie beside it; sumotest_containers_bidi), and the fill wants an area."""
    clipped = (max(b0, lo), min(b1, hi))
    return clipped if clipped[1] - clipped[0] >= MIN_AREA_WIDTH else (lo, hi)


def _one_line(text: str) -> str:
    """The line that says what went wrong: SUMO's Error line, else the traceback's last line."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith(("Error:", "error:", "Quitting"))]
    pick = next((ln for ln in errors if not ln.startswith("Quitting")), None) or (lines[-1] if lines else "")
    return pick[:300]


def step(cmd: list, timeout: float, log: Path, cwd: Path) -> dict:
    """One subprocess with its own time limit; its output to ``log``; ok, seconds, one line."""
    t0 = time.monotonic()
    log.parent.mkdir(parents=True, exist_ok=True)
    # its own process group: the `sumo` entry point is a wrapper around the binary, and a timeout must
    # end both (a binary waiting for a TraCI client would hold its port)
    p = subprocess.Popen([str(c) for c in cmd], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         cwd=cwd, stdin=subprocess.DEVNULL, start_new_session=True, env=product_env())
    try:
        out, err = p.communicate(timeout=timeout)
        rc = p.returncode
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        err, rc = err + f"\ntimeout after {timeout:.0f} s", None
    log.write_text(f"$ {' '.join(map(str, cmd))}\n--- stdout\n{out}\n--- stderr\n{err}\n")
    res = {"ok": rc == 0, "seconds": round(time.monotonic() - t0, 1), "cmd": " ".join(map(str, cmd)),
           "returncode": rc}
    if rc != 0:
        res["error"] = _one_line(err) or _one_line(out)
    return res


def product_env() -> dict:
    """The environment of a step: the product imported from this work tree (``ROOT``), the one each row's
    ``product`` names, whichever checkout an editable install of the package points to."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path}


def placement(doc_path: Path) -> dict | None:
    """Agents by status in a scene.json / fill.json (every list named ``agents``, at any depth)."""
    if not doc_path.is_file():
        return None
    counts: dict = {}

    def walk(node):
        if isinstance(node, dict):
            for k, v in node.items():
                if k == "agents" and isinstance(v, list):
                    for a in v:
                        if isinstance(a, dict) and "status" in a:
                            counts[a["status"]] = counts.get(a["status"], 0) + 1
                else:
                    walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)
    walk(json.loads(doc_path.read_text()))
    return {"agents": sum(counts.values()), **counts, "placed_share": placed_share(counts)}


SEEDED = ("placed", "misplaced", "refused")   # the agents the product tried to put into SUMO


def placed_share(counts: dict) -> float | None:
    """Placed among the agents it tried to seed (placed, misplaced, refused: sim.seed_report.SEEDED); an
    ``existing`` agent is the model's copy of a vehicle already there (kept, the copy not added), a
    ``dropped`` one was not seeded by the seeder's rules (a place taken…); each with its reason."""
    tried = sum(counts.get(k, 0) for k in SEEDED)
    return round(counts.get("placed", 0) / tried, 4) if tried else None


def commands(cfg: Path, t: float, area: tuple, out: Path, scenes: int = 2, rollout: float = ROLL,
             clock: bool = False) -> dict:
    """Each step's argument list (STEPS order): stock SUMO, run, its replay, fill, its two replays;
    ``clock``: the product's --begin as SUMO's H:MM:SS."""
    py, end = sys.executable, f"{t + ROLL:g}"
    clock_time = f"{int(t // 3600)}:{int(t % 3600 // 60):02d}:" + f"{t % 60:05.2f}".removesuffix(".00")
    begin = clock_time if clock else f"{t:g}"
    a = ",".join(f"{v:.1f}" for v in area)
    return {
        # a configuration's output-prefix (MoST's "most.") would rename the summary the row reads
        "sumo": [_sumo(), "-c", cfg, "--end", end, "--no-step-log", "true", "--output-prefix", "",
                 "--summary-output", out / "sumo_summary.xml"],
        "run": [py, "-m", "sumo_scendiff.run", "-c", cfg, "--begin", begin, "--scenes", str(scenes),
                "--rollout", f"{rollout:g}", "-o", out / "run"],
        "run_replay": [_sumo(), "-c", out / "run" / "scene_000" / "scenario.sumocfg", "--end", f"{t + 5:g}",
                       "--no-step-log", "true", "--summary-output", out / "run_replay_summary.xml"],
        "fill": [py, "-m", "sumo_scendiff.fill", "-c", cfg, "--begin", begin, f"--area={a}",
                 "-o", out / "fill"],
        "fill_replay": [_sumo(), "-c", out / "fill" / "scenario.sumocfg", "--end", end,
                        "--no-step-log", "true", "--summary-output", out / "fill_replay_summary.xml"],
        "fill_start": [_sumo(), "-c", out / "fill" / "start.sumocfg", "--end", end,
                       "--no-step-log", "true", "--summary-output", out / "fill_start_summary.xml"],
    }


def run_scenario(sc: Scenario, cache: Path, mirror: Path | None = None) -> dict:
    row = {"name": sc.name, "source": sc.source, "licence": sc.licence, "covers": list(sc.covers),
           "note": sc.note, "product": _product_state(), "steps": {}}
    try:
        cfg = build(sc, cache, mirror)
    except Exception as e:     # noqa: BLE001 -- a source that cannot be had is a row, not a crash
        row["steps"]["build"] = {"ok": False, "error": f"{type(e).__name__}: {e}"[:300]}
        return row
    t, area = begin_time(sc, cfg), fill_area(sc, cfg)
    row.update(config=str(cfg), begin=t, area=list(area))
    out = cache / "_out" / sc.name
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    for name, cmd in commands(cfg, t, area, out, clock=sc.clock).items():
        if name in NEEDS and not row["steps"][NEEDS[name]]["ok"]:
            row["steps"][name] = {"ok": None, "error": f"skip: {NEEDS[name]} failed"}
            continue
        if name in NEEDS and not Path(cmd[2]).is_file():
            # the product finished and said why it exported nothing (a network without car lanes)
            row["steps"][name] = {"ok": None, "error": f"skip: {NEEDS[name]} wrote no {Path(cmd[2]).name}"}
            continue
        limit = sc.timeout.get(name, TIMEOUT[name])
        before = set(out.iterdir())
        res = check_count(name, step(cmd, limit, out / "logs" / f"{name}.log", out), out)
        row["steps"][name] = stray_outputs(name, res, out, before)
    row["sumo_running_at_T"] = running_at(out / "sumo_summary.xml", t)
    row["placement_run"] = placement(out / "run" / "scene_000" / "scene.json")
    row["placement_fill"] = placement(out / "fill" / "fill.json")
    return row


def stray_outputs(name: str, res: dict, out: Path, before: set) -> dict:
    """``res`` of the product's step (run, fill) failed where it wrote into its working directory (``out``)
    anything but its ``-o`` folder: a scenario's output SUMO writes where it runs (an SSM device's
    ssm_<vehicle>.xml) is its user's business, not the product's to write beside them."""
    if name not in ("run", "fill") or not res.get("ok"):
        return res
    stray = sorted(p.name for p in set(out.iterdir()) - before - {out / name})
    if not stray:
        return res
    return {**res, "ok": False, "error": f"wrote {len(stray)} files into its working directory: "
                                         + ", ".join(stray[:3])}


# --------------------------------------------------------------------------- the table

STEPS = ["sumo", "run", "run_replay", "fill", "fill_replay", "fill_start"]
MARK = {True: "ok", False: "FAIL", None: "skip"}


def first_failure(row: dict) -> tuple:
    for name in ["build"] + STEPS:
        s = row["steps"].get(name)
        if s is not None and s.get("ok") is False:
            return name, s.get("error", ""), s.get("cmd", "")
    return None, "", ""


def _share(p: dict | None) -> str:
    if not p or not p.get("agents"):
        return "–" if p is None else "0 agents"
    share, tried = placed_share(p), sum(p.get(k, 0) for k in SEEDED)
    text = f"{100 * share:.1f} % of {tried}" if share is not None else "none seeded"
    others = [f"{p[k]} {k}" for k in sorted(p) if k not in SEEDED + ("agents", "placed_share") and p[k]]
    return text + (f" ({', '.join(others)})" if others else "")


def _or_dash(v) -> str:
    return "–" if v is None else str(v)


def _seconds(row: dict, name: str) -> str:
    s = row["steps"].get(name) or {}
    return f"{s['seconds']:.0f}" if s.get("seconds") is not None and s.get("ok") is not None else "–"


def _current(row: dict) -> dict:
    """A results row with the registry's present source, licence and coverage for its scenario."""
    sc = next((s for s in REGISTRY if s.name == row["name"]), None)
    return row if sc is None else {**row, "source": sc.source, "licence": sc.licence, "covers": list(sc.covers),
                                   "note": sc.note}


def markdown(rows: list) -> str:
    head = ("| scenario | source | licence | covers | " + " | ".join(STEPS)
            + " | SUMO's vehicles at T | placed (run) | placed (fill) | time s sumo / run / fill | first failure |")
    lines = [head, "|" + "---|" * (len(STEPS) + 9)]
    for r in map(_current, rows):
        marks = [MARK[r["steps"][n]["ok"]] if n in r["steps"] else "–" for n in STEPS]
        if "build" in r["steps"]:
            marks = ["not built"] + ["–"] * (len(STEPS) - 1)
        step_name, err, _ = first_failure(r)
        err = err.replace(str(DEFAULT_CACHE) + "/", "").replace(f"{sys.executable} ", "python ")
        fail = f"{step_name}: {err}".replace("|", "\\|") if step_name else ""
        fail += f" ({r['note']})" if r.get("note") else ""
        times = " / ".join(_seconds(r, n) for n in ("sumo", "run", "fill"))
        figures = [_or_dash(r.get("sumo_running_at_T")), _share(r.get("placement_run")),
                   _share(r.get("placement_fill")), times, fail]
        lines.append(f"| {r['name']} | {r['source']} | {r['licence']} | {', '.join(r['covers'])} | "
                     + " | ".join(marks + figures) + " |")
    return "\n".join(lines) + "\n"


def _merge(path: Path, rows: list) -> list:
    """Rows of an earlier results file for scenarios not run now, in registry order."""
    old = {}
    if path and path.is_file():
        old = {r["name"]: r for r in json.loads(path.read_text()).get("scenarios", [])}
    old.update({r["name"]: r for r in rows})
    order = [s.name for s in REGISTRY]
    return sorted(old.values(), key=lambda r: order.index(r["name"]) if r["name"] in order else 1e9)


def _write_markdown(path: Path, table: str) -> None:
    """The table between the markers of ``path`` (docs/corpus.md), or the whole file if it has none."""
    begin, end = "<!-- corpus-table -->", "<!-- /corpus-table -->"
    text = path.read_text() if path.is_file() else ""
    if begin in text and end in text:
        text = text[:text.index(begin) + len(begin)] + "\n" + table + text[text.index(end):]
    else:
        text = table
    path.write_text(text)



def _product_state() -> str:
    """The commit the product ran at, ``+changes`` when the work tree differed from it."""
    git = ["git", "-C", str(ROOT)]
    head = subprocess.run(git + ["rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(git + ["status", "--porcelain", "--", "sumo_scendiff"], capture_output=True,
                           text=True).stdout.strip()
    return head + ("+changes" if dirty else "")
