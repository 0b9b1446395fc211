"""A public scenario corpus: SUMO scenarios as their authors ship them, run through the product as a new
user would, beside stock SUMO.

    python benchmarks/scenarios.py list                        # the registry
    python benchmarks/scenarios.py build [--only NAME ...]     # into the cache, nothing into git
    python benchmarks/scenarios.py run [--only NAME ...] [--jobs 1] [--results results/corpus.json]
                                       [--markdown docs/corpus.md]
    python benchmarks/scenarios.py table --results results/corpus.json --markdown docs/corpus.md

The cache is ``~/.cache/sumo-scendiff/corpus`` (``--cache DIR``); each scenario is a folder there with
the configuration, every file it names (paths kept relative, as its authors laid them out) and
``source.json``: how the folder was obtained, so it can be rebuilt (the SUMO wheel's version; the PyPI
package, version and wheel sha256; a GitHub repository, commit and paths).

Sources (docs/corpus.md lists every scenario with its licence):

* ``sumo-wheel``: the eclipse-sumo wheel's ``tools/game`` scenarios (EPL-2.0), copied from SUMO_HOME.
* ``pypi``: scenarios shipped inside a PyPI package, downloaded with ``pip download PKG==VER --no-deps``
  (sumo-rl: its own nets and RESCO's; MIT).
* ``github``: files of a public repository at a fixed commit, read from a local git mirror
  (``--mirror DIR``, ``DIR/owner+name/repo``) or from ``CACHE/_github/owner+name/COMMIT/PATH`` where
  they were saved before; nothing is fetched here, and a scenario whose files are not there is reported
  as not built.

For each scenario ``run`` does, every step a subprocess with its own time limit:

1. ``sumo -c CFG --end T+30``: the reference (did stock SUMO run it, how long).
2. ``python -m sumo_scendiff.run -c CFG --begin T --scenes 2 --rollout 30 -o OUT/run``
3. ``sumo -c OUT/run/scene_000/scenario.sumocfg --end T+5`` (the exported scene, from its saved state
   at T, in stock SUMO)
4. ``python -m sumo_scendiff.fill -c CFG --begin T --area X0,Y0,X1,Y1 -o OUT/fill``
5. ``sumo -c OUT/fill/scenario.sumocfg`` and ``sumo -c OUT/fill/start.sumocfg``, each to T+30.

T is the scenario's begin (its configuration's, unless the registry names one) plus ``offset``; the
area is the registry's, else a square of ``AREA_SIDE`` m about the median of the car edges' junctions.
Placement is the share of scene.json / fill.json agents whose status is ``placed`` among those the product
tried to seed (placed, misplaced, refused); dropped and conflicting ones are counted beside it.
A step after a failed one that it needs is ``skip``. One table: markdown (``--markdown``) and JSON
(``--results``), with the first failing step's one line and its command.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = Path.home() / ".cache" / "sumo-scendiff" / "corpus"
AREA_SIDE = 400.0      # m: the fill's square when the registry names no area
ROLL = 30.0            # s: how far past T stock SUMO runs each configuration
TIMEOUT = {"sumo": 600, "run": 1200, "run_replay": 300, "fill": 1500, "fill_replay": 600,
           "fill_start": 600}


@dataclasses.dataclass(frozen=True)
class Scenario:
    name: str
    source: str            # where it comes from, for the table
    licence: str
    get: dict              # how to obtain it: kind (sumo-wheel / pypi / github) and its fields
    config: str            # the .sumocfg, relative to the scenario folder
    covers: tuple = ()     # what it exercises: left-hand, bicycles, trams, buses, pedestrians, ...
    begin: float | None = None   # T; None: the configuration's begin + offset
    offset: float = 120.0
    area: tuple | None = None
    timeout: dict = dataclasses.field(default_factory=dict)   # step -> s, over TIMEOUT
    note: str = ""


def _game(name, cfg, covers=(), **kw):
    return Scenario(name, "SUMO tools/game (eclipse-sumo wheel)", "EPL-2.0",
                    {"kind": "sumo-wheel", "path": f"tools/game/{cfg}"}, Path(cfg).name, covers, **kw)


SUMO_RL = {"kind": "pypi", "package": "sumo-rl", "version": "1.4.5"}


def _sumo_rl(name, cfg, covers=(), source="sumo-rl (PyPI)", **kw):
    return Scenario(name, source, "MIT", dict(SUMO_RL, path=f"sumo_rl/nets/{cfg}"), Path(cfg).name,
                    covers, **kw)


def _github(name, repo, files, cfg, licence, covers=(), steps=(), **kw):
    """``files``: the scenario folder's path -> (path in the repository, commit); ``steps``: the
    commands its authors give to build the rest (a SUMO binary or a SUMO tool's script, then its
    arguments), run in the folder in order."""
    return Scenario(name, f"github:{repo}", licence,
                    {"kind": "github", "repo": repo, "files": {k: list(v) for k, v in files.items()},
                     "steps": [list(c) for c in steps]}, cfg, covers, **kw)


SUMO_REPO = "eclipse-sumo/sumo"
MANHATTAN = "tests/complex/tutorial/manhattan/data/"


REGISTRY: list[Scenario] = [
    _game("game_cross", "cross.sumocfg", ("lights", "TLS program file"), offset=60),
    _game("game_square", "square.sumocfg", ("right of way",), offset=60),
    _game("game_ramp", "ramp.sumocfg", ("highway", "on-ramp"), offset=60),
    _game("game_corridor", "corridor.sumocfg", ("arterial", "lights"), offset=60),
    _game("game_grid6", "grid6.sumocfg", ("grid", "lights"), offset=60),
    _game("game_fkk_in", "fkk_in.sumocfg", ("city", "lights"), offset=60),
    _game("game_bs3d", "bs3d.sumocfg", ("city", "pedestrians"), offset=60),
    _game("game_A10KW", "A10KW.sumocfg", ("highway", "trucks"), offset=300),
    _game("game_rail", "rail.sumocfg", ("rail", "stops", "rerouters"), offset=120),
    _game("game_DRT", "DRT.sumocfg", ("buses", "taxis", "persons", "stops"), offset=120),
    _game("game_DRT2", "DRT2.sumocfg", ("buses", "taxis", "persons", "stops"), offset=120),
    _game("game_fokr_bs", "fokr_bs_demo.sumocfg", ("bicycles", "pedestrians", "trips"), offset=60),
    _game("game_rail_demo", "rail_demo.sumocfg", ("rail",), offset=120),
    _sumo_rl("sumorl_single_intersection", "single-intersection/single-intersection.sumocfg",
             ("lights",)),
    _sumo_rl("sumorl_2way_single", "2way-single-intersection/single-intersection.sumocfg", ("lights",)),
    _sumo_rl("sumorl_3x3grid", "3x3grid/3x3grid.sumocfg", ("grid",)),
    _sumo_rl("sumorl_4x4_lucas", "4x4-Lucas/4x4.sumocfg", ("grid", "lights")),
    _sumo_rl("sumorl_4x4loop", "4x4loop/4x4loop.sumocfg", ("grid", "loop")),
    _sumo_rl("sumorl_nguyen", "Nguyen/nguyen.sumocfg", ("flows", "TAZ")),
    _sumo_rl("sumorl_ow", "OW/OW-traci.sumocfg", ("arterial", "TraCI port"),
             timeout={"sumo": 60, "run": 120, "fill": 120},
             note="its configuration sets remote-port: stock sumo waits for a TraCI client"),
    _sumo_rl("sumorl_simple", "simple/simple.sumocfg", ()),
    _sumo_rl("resco_arterial4x4", "RESCO/arterial4x4/arterial4x4.sumocfg", ("arterial", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_grid4x4", "RESCO/grid4x4/grid4x4.sumocfg", ("grid", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_cologne1", "RESCO/cologne1/cologne1.sumocfg", ("city", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_cologne3", "RESCO/cologne3/cologne3.sumocfg", ("city", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_cologne8", "RESCO/cologne8/cologne8.sumocfg", ("city", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_ingolstadt1", "RESCO/ingolstadt1/ingolstadt1.sumocfg", ("city", "lights", "buses"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_ingolstadt7", "RESCO/ingolstadt7/ingolstadt7.sumocfg", ("city", "lights", "buses"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_ingolstadt21", "RESCO/ingolstadt21/ingolstadt21.sumocfg", ("city", "lights", "buses"),
             source="RESCO via sumo-rl (PyPI)"),
    _github("tutorial_manhattan", SUMO_REPO,
            {"manhattan.netgcfg": (MANHATTAN + "manhattan.netgcfg", "5629ad53b59bd84a98083b544c472c050eb1aeb8"),
             "manhattan.jtrrcfg": (MANHATTAN + "manhattan.jtrrcfg", "5629ad53b59bd84a98083b544c472c050eb1aeb8"),
             "manhattan.sumocfg": (MANHATTAN + "manhattan.sumocfg", "6b9178fc9d7b59efd33ab6f9dc98ea86bf1a57f8")},
            "manhattan.sumocfg", "EPL-2.0", ("grid", "jtrrouter flows"),
            steps=[["netgenerate", "-c", "manhattan.netgcfg", "-o", "net.net.xml"],
                   ["randomTrips.py", "--flows", "100", "-b", "0", "-e", "1", "-n", "net.net.xml", "-o",
                    "flows.xml", "--jtrrouter", "--trip-attributes", 'departPos="random" departSpeed="max"',
                    "--seed", "42"],
                   ["jtrrouter", "-c", "manhattan.jtrrcfg"]], offset=300),
    Scenario("lust_osm_wizard", "github:lcodeca/LuSTScenario, built by SUMO's osmWebWizard", "MIT (OSM: ODbL)",
             {"kind": "osm-wizard", "repo": "lcodeca/LuSTScenario",
              "commit": "5edb7ecb9ad196c39172b6eb95d19ed789f4b1a6", "path": "misc/lust.legacy.scenario.osm"},
             "osm.sumocfg", ("city", "roundabouts", "actuated lights", "bicycles", "pedestrians", "OSM"),
             offset=300),
    Scenario("gen_lefthand_grid", "built by SUMO's netgenerate + randomTrips", "EPL-2.0",
             {"kind": "generate", "netgenerate": ["--grid", "--grid.number", "4", "--grid.length", "150",
                                                  "--default.lanenumber", "2", "--lefthand", "--tls.guess",
                                                  "--sidewalks.guess", "--crossings.guess"],
              "trips": {"passenger": ["--period", "2"], "bicycle": ["--period", "8"],
                        "pedestrian": ["--period", "6", "--pedestrians"]}},
             "scenario.sumocfg", ("left-hand", "lights", "bicycles", "pedestrians")),
    Scenario("gen_lefthand_spider", "built by SUMO's netgenerate + randomTrips", "EPL-2.0",
             {"kind": "generate", "netgenerate": ["--spider", "--spider.arm-number", "6",
                                                  "--spider.circle-number", "4", "--spider.space-radius", "80",
                                                  "--lefthand", "--default.junctions.radius", "6"],
              "trips": {"passenger": ["--period", "1.5"], "truck": ["--period", "10"],
                        "motorcycle": ["--period", "6"]}},
             "scenario.sumocfg", ("left-hand", "right of way", "trucks", "motorcycles")),
]


# --------------------------------------------------------------------------- building the cache

def _sumo_home() -> Path:
    import sumo
    return Path(sumo.SUMO_HOME)


def _named_files(cfg: Path) -> list[str]:
    """Every file a configuration names that exists beside it (relative paths as written)."""
    found = []
    for el in ET.parse(cfg).getroot().iter():
        for token in (el.get("value") or "").replace(",", " ").split():
            if (cfg.parent / token).is_file() and token not in found:
                found.append(token)
    return found


def _copy_scenario(cfg: Path, dest: Path) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy2(cfg, dest / cfg.name)
    for rel in _named_files(cfg):
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(cfg.parent / rel, dest / rel)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _from_wheel(sc: Scenario, dest: Path, cache: Path) -> dict:
    from importlib.metadata import version
    _copy_scenario(_sumo_home() / sc.get["path"], dest)
    return {"eclipse-sumo": version("eclipse-sumo")}


def _pypi_wheel(package: str, ver: str, cache: Path) -> Path:
    """The package's wheel under CACHE/_downloads, by pip's own client (once)."""
    down = cache / "_downloads"
    stem = package.replace("-", "_")
    hits = sorted(down.glob(f"{stem}-{ver}-*.whl"))
    if not hits:
        subprocess.run([sys.executable, "-m", "pip", "download", f"{package}=={ver}", "--no-deps",
                        "--only-binary", ":all:", "-d", str(down), "-q"], check=True, timeout=600)
        hits = sorted(down.glob(f"{stem}-{ver}-*.whl"))
    return hits[0]


def _from_pypi(sc: Scenario, dest: Path, cache: Path) -> dict:
    wheel = _pypi_wheel(sc.get["package"], sc.get["version"], cache)
    unpacked = cache / "_downloads" / wheel.stem
    if not unpacked.is_dir():
        with zipfile.ZipFile(wheel) as z:
            z.extractall(unpacked)
    _copy_scenario(unpacked / sc.get["path"], dest)
    return {"wheel": wheel.name, "sha256": _sha256(wheel)}


def _github_file(repo: str, commit: str, path: str, cache: Path, mirror: Path | None) -> bytes:
    """A repository's file at a commit: saved in the cache before, else from a git mirror (then saved)."""
    saved = cache / "_github" / repo.replace("/", "+") / commit / path
    if saved.is_file():
        return saved.read_bytes()
    gitdir = mirror / repo.replace("/", "+") / "repo" if mirror else None
    if gitdir is None or not gitdir.is_dir():
        raise FileNotFoundError(f"github:{repo} {path}@{commit[:10]} is neither saved at {saved} nor mirrored"
                                + (f" at {gitdir}" if gitdir else " (--mirror)"))
    out = subprocess.run(["git", "--git-dir", str(gitdir), "show", f"{commit}:{path}"],
                         capture_output=True, check=True, timeout=120).stdout
    saved.parent.mkdir(parents=True, exist_ok=True)
    saved.write_bytes(out)
    return out


def _from_github(sc: Scenario, dest: Path, cache: Path, mirror: Path | None) -> dict:
    g = sc.get
    for rel, (path, commit) in g["files"].items():
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        (dest / rel).write_bytes(_github_file(g["repo"], commit, path, cache, mirror))
    for cmd in g["steps"]:
        prog = [sys.executable, _tool(cmd[0])] if cmd[0].endswith(".py") else \
            [shutil.which(cmd[0]) or str(_sumo_home() / "bin" / cmd[0])]
        subprocess.run(prog + cmd[1:], cwd=dest, check=True, capture_output=True, timeout=1800)
    return {}


def _tool(name: str) -> str:
    return str(_sumo_home() / "tools" / name)


def _from_osm_wizard(sc: Scenario, dest: Path, cache: Path, mirror: Path | None) -> dict:
    """An OSM file built into a scenario as SUMO's osmWebWizard does (its non-interactive mode)."""
    g = sc.get
    osm = cache / "_downloads" / f"{sc.name}.osm"
    osm.parent.mkdir(parents=True, exist_ok=True)
    osm.write_bytes(_github_file(g["repo"], g["commit"], g["path"], cache, mirror))
    # the wizard builds in a fresh temporary folder when its output folder exists already
    cmd = [sys.executable, _tool("osmWebWizard.py"), "--osm-file", str(osm), "--test-output", str(dest),
           "--remote"] + g.get("options", [])
    subprocess.run(cmd, cwd=cache, check=True, capture_output=True, timeout=1800)
    return {"built_with": ["osmWebWizard.py", "--osm-file", osm.name, "--test-output", dest.name, "--remote",
                           *g.get("options", [])]}


def _from_generate(sc: Scenario, dest: Path, cache: Path) -> dict:
    """A network by SUMO's netgenerate and demand by its randomTrips (seeded), one configuration."""
    g, end = sc.get, "900"
    dest.mkdir(parents=True)
    netgen = shutil.which("netgenerate") or str(_sumo_home() / "bin" / "netgenerate")
    subprocess.run([netgen, *g["netgenerate"], "-o", "net.net.xml", "--seed", "42"], cwd=dest, check=True,
                   capture_output=True, timeout=600)
    routes = []
    for vclass, extra in g["trips"].items():
        out = f"{vclass}.rou.xml"
        prefix = ["--vehicle-class", vclass, "--vclass", vclass] if vclass != "pedestrian" else []
        subprocess.run([sys.executable, _tool("randomTrips.py"), "-n", "net.net.xml", "-e", end, "--seed", "42",
                        "--prefix", vclass[:3], "--validate", "-r", out, "-o", f"{vclass}.trips.xml",
                        *prefix, *extra], cwd=dest, check=True, capture_output=True, timeout=600)
        routes.append(out)
    (dest / sc.config).write_text(
        '<configuration>\n    <input>\n        <net-file value="net.net.xml"/>\n'
        f'        <route-files value="{",".join(routes)}"/>\n    </input>\n'
        f'    <time>\n        <begin value="0"/>\n        <end value="{end}"/>\n    </time>\n'
        '</configuration>\n')
    return {"built_with": {"netgenerate": g["netgenerate"], "randomTrips": g["trips"]}}


def build(sc: Scenario, cache: Path, mirror: Path | None = None, force: bool = False) -> Path:
    """The scenario's configuration in the cache, building its folder first if needed."""
    dest = cache / sc.name
    cfg = dest / sc.config
    if cfg.is_file() and (dest / "source.json").is_file() and not force:
        return cfg
    if dest.exists():
        shutil.rmtree(dest)
    part = cache / f"{sc.name}.partial"
    shutil.rmtree(part, ignore_errors=True)
    kind = sc.get["kind"]
    if kind == "sumo-wheel":
        extra = _from_wheel(sc, part, cache)
    elif kind == "pypi":
        extra = _from_pypi(sc, part, cache)
    elif kind == "osm-wizard":
        extra = _from_osm_wizard(sc, part, cache, mirror)
    elif kind == "generate":
        extra = _from_generate(sc, part, cache)
    else:
        extra = _from_github(sc, part, cache, mirror)
    record = {"name": sc.name, "source": sc.source, "licence": sc.licence, "get": sc.get,
              "config": sc.config, **extra}
    (part / "source.json").write_text(json.dumps(record, indent=1) + "\n")
    part.rename(dest)
    return cfg


# --------------------------------------------------------------------------- running a scenario

def _config_value(cfg: Path, key: str) -> str | None:
    for el in ET.parse(cfg).getroot().iter(key):
        return el.get("value")
    return None


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


def car_centre(net: Path) -> tuple:
    """The median of the car edges' junction positions: inside the network's streets (a rail or
    pedestrian fringe can move a bounding box's centre off every car lane)."""
    import statistics
    import sumolib
    xs, ys = [], []
    for e in sumolib.net.readNet(str(net)).getEdges(withInternal=False):
        if e.allows("passenger"):
            for node in (e.getFromNode(), e.getToNode()):
                xs.append(node.getCoord()[0])
                ys.append(node.getCoord()[1])
    return (statistics.median(xs), statistics.median(ys)) if xs else None


def fill_area(sc: Scenario, cfg: Path, side: float = AREA_SIDE) -> tuple:
    if sc.area is not None:
        return sc.area
    net = cfg.parent / _config_value(cfg, "net-file")
    x0, y0, x1, y1 = net_boundary(net)
    (cx, cy), h = car_centre(net) or ((x0 + x1) / 2, (y0 + y1) / 2), side / 2
    return (max(x0, cx - h), max(y0, cy - h), min(x1, cx + h), min(y1, cy + h))


def _sumo() -> str:
    return shutil.which("sumo") or str(_sumo_home() / "bin" / "sumo")


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
                         cwd=cwd, stdin=subprocess.DEVNULL, start_new_session=True)
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
    """Placed among the agents it tried to seed: a ``dropped`` agent is the model's copy of a vehicle
    already there, a ``conflict`` one overlapped a vehicle seeded before (each with its reason)."""
    tried = sum(counts.get(k, 0) for k in SEEDED)
    return round(counts.get("placed", 0) / tried, 4) if tried else None


def commands(cfg: Path, t: float, area: tuple, out: Path, scenes: int = 2, rollout: float = ROLL) -> dict:
    """Each step's argument list (STEPS order): stock SUMO, run, its replay, fill, its two replays."""
    py, end = sys.executable, f"{t + ROLL:g}"
    a = ",".join(f"{v:.1f}" for v in area)
    return {
        "sumo": [_sumo(), "-c", cfg, "--end", end, "--no-step-log", "true",
                 "--summary-output", out / "sumo_summary.xml"],
        "run": [py, "-m", "sumo_scendiff.run", "-c", cfg, "--begin", f"{t:g}", "--scenes", str(scenes),
                "--rollout", f"{rollout:g}", "-o", out / "run"],
        "run_replay": [_sumo(), "-c", out / "run" / "scene_000" / "scenario.sumocfg", "--end", f"{t + 5:g}",
                       "--no-step-log", "true"],
        "fill": [py, "-m", "sumo_scendiff.fill", "-c", cfg, "--begin", f"{t:g}", f"--area={a}",
                 "-o", out / "fill"],
        "fill_replay": [_sumo(), "-c", out / "fill" / "scenario.sumocfg", "--end", end,
                        "--no-step-log", "true"],
        "fill_start": [_sumo(), "-c", out / "fill" / "start.sumocfg", "--end", end,
                       "--no-step-log", "true"],
    }


def running_at(summary: Path, t: float) -> int | None:
    """Vehicles on the road in stock SUMO's run at T (its summary-output): how much traffic the product
    was given to fill around."""
    running = None
    if summary.is_file():
        for _, el in ET.iterparse(summary):
            if el.tag == "step" and float(el.get("time")) <= t + 1e-6:
                running = int(el.get("running"))
            el.clear()
    return running


NEEDS = {"run_replay": "run", "fill_replay": "fill", "fill_start": "fill"}


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
    for name, cmd in commands(cfg, t, area, out).items():
        if name in NEEDS and not row["steps"][NEEDS[name]]["ok"]:
            row["steps"][name] = {"ok": None, "error": f"skip: {NEEDS[name]} failed"}
            continue
        if name in NEEDS and not Path(cmd[2]).is_file():
            # the product finished and said why it exported nothing (a network without car lanes)
            row["steps"][name] = {"ok": None, "error": f"skip: {NEEDS[name]} wrote no {Path(cmd[2]).name}"}
            continue
        limit = sc.timeout.get(name, TIMEOUT[name])
        row["steps"][name] = step(cmd, limit, out / "logs" / f"{name}.log", out)
    row["sumo_running_at_T"] = running_at(out / "sumo_summary.xml", t)
    row["placement_run"] = placement(out / "run" / "scene_000" / "scene.json")
    row["placement_fill"] = placement(out / "fill" / "fill.json")
    return row


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


# --------------------------------------------------------------------------- command line

def _selected(only: list) -> list:
    if not only:
        return REGISTRY
    names = {s.name for s in REGISTRY}
    unknown = [n for n in only if n not in names]
    if unknown:
        sys.exit(f"scenarios.py: --only: no scenario named {', '.join(unknown)} (see `list`)")
    return [s for s in REGISTRY if s.name in only]


def _cmd_list(o) -> None:
    for s in _selected(o.only):
        print(f"{s.name:30s} {s.licence:10s} {s.source:40s} {', '.join(s.covers)}")
    print(f"{len(_selected(o.only))} scenarios")


def _cmd_build(o) -> None:
    for s in _selected(o.only):
        try:
            print(s.name, build(s, o.cache, o.mirror, force=o.force))
        except Exception as e:      # noqa: BLE001 -- report each source that cannot be had
            print(s.name, "not built:", e)


def _cmd_run(o) -> None:
    from tqdm import tqdm
    scenarios, rows = _selected(o.only), []
    with ThreadPoolExecutor(max_workers=o.jobs) as pool, \
            tqdm(total=len(scenarios), desc="corpus", unit="scenario") as bar:
        for row in pool.map(lambda s: run_scenario(s, o.cache, o.mirror), scenarios):
            rows.append(row)
            bar.set_postfix_str(f"{row['name']}: {first_failure(row)[0] or 'ok'}")
            bar.update()
            if o.results:      # after every scenario, so a long run can be read as it goes
                _save(o, _merge(o.results, rows))
    table = markdown(_merge(o.results, rows) if o.results else rows)
    print(table)
    if o.markdown:
        _write_markdown(o.markdown, table)


def _product_state() -> str:
    """The commit the product ran at, ``+changes`` when the work tree differed from it."""
    git = ["git", "-C", str(ROOT)]
    head = subprocess.run(git + ["rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(git + ["status", "--porcelain", "--", "sumo_scendiff"], capture_output=True,
                           text=True).stdout.strip()
    return head + ("+changes" if dirty else "")


def _cmd_table(o) -> None:
    """The table again from ``--results`` (no scenario is run)."""
    if not o.results or not o.results.is_file():
        sys.exit("scenarios.py: table: --results names no results file")
    table = markdown(_merge(o.results, []))
    print(table)
    if o.markdown:
        _write_markdown(o.markdown, table)


def _save(o, rows: list) -> None:
    o.results.parent.mkdir(parents=True, exist_ok=True)
    o.results.write_text(json.dumps({"format": "sumo-scendiff-corpus", "version": 1,
                                     "scenarios": rows}, indent=1) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("command", choices=["list", "build", "run", "table"])
    ap.add_argument("--only", nargs="+", default=[], metavar="NAME")
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    ap.add_argument("--mirror", type=Path, help="git mirrors of the GitHub sources (DIR/owner+name/repo)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--force", action="store_true", help="build: rebuild existing folders")
    ap.add_argument("--results", type=Path, help="JSON results, merged with an existing file")
    ap.add_argument("--markdown", type=Path, help="write the table (between the markers of docs/corpus.md)")
    o = ap.parse_args(argv)
    o.cache = o.cache.expanduser()
    {"list": _cmd_list, "build": _cmd_build, "run": _cmd_run, "table": _cmd_table}[o.command](o)


if __name__ == "__main__":
    main()
