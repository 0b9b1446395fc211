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
* ``generate``: a network by SUMO's netgenerate and demand by its randomTrips (seeded).
* ``feature``: the feature matrix (``scenarios_features.py``): a small generated grid with lights plus one
  SUMO feature real-world scenarios use (mesoscopic, sublane, persons, parking, TAZ, trams, ...).

The code beside this command line: ``scenarios_registry.py`` (the rows), ``scenarios_build.py`` (the cache),
``scenarios_features.py`` and ``scenarios_features_more.py`` (the feature variants' builders), ``scenarios_run.py``
(the steps and the table), ``scenarios_counts.py`` (what each replay must hold).

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
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

# the corpus's modules sit beside this script; put them on the path when it is loaded by file (tests, report.py)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
# and the product from this work tree, as its steps run it (scenarios_run.product_env)
sys.path.insert(1, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from scenarios_build import _named_files, _sumo_home, build  # noqa: E402,F401 -- the corpus's interface
from scenarios_registry import REGISTRY, Scenario  # noqa: E402,F401
from scenarios_counts import _sumo, check_count, running_at  # noqa: E402,F401
from scenarios_run import (DEFAULT_CACHE, TIMEOUT, _merge, _one_line, _share, _write_markdown,  # noqa: E402,F401
                           begin_time, commands, fill_area, first_failure, markdown, placement, run_scenario, step)


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
