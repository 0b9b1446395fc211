"""Batch token sweeps: many scenarios from one spec file, in parallel, resumable.

    python -m sumo_scendiff.sweep --spec scenarios/truck_stopping.toml --out sweeps/truck
    python -m sumo_scendiff.sweep --spec scenarios/density.json --out sweeps/density --workers 2
    python -m sumo_scendiff.sweep --spec scenarios/density.json --out sweeps/density --resume
    python -m sumo_scendiff.sweep --spec ... --out ... --engine ray [--ray-address HOST:PORT]

The spec (``docs/sweeps.md``) names networks, locations, token sets and their variants, p_mask
values and seeds; the sweep is their cross product (or an explicit list). Each scenario is written
as ``run`` writes one (``OUT/sNNNN/``, via a ``.partial`` folder renamed when complete); then
``OUT/index.csv`` / ``index.jsonl`` (one row per scenario: parameters, scene and rollout
statistics), ``OUT/contact_sheet.png`` and ``OUT/stats.png``. A sweep that was killed, even with
SIGKILL, continues with ``--resume``: only missing scenarios run, the index is rebuilt.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

PROG = "python -m sumo_scendiff.sweep"


def get_options(args=None):
    from ..core.cli import HelpFormatter, description, epilog
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), epilog=epilog(__doc__),
                                formatter_class=HelpFormatter)
    p.add_argument("--spec", required=True, help="sweep spec (TOML or JSON)")
    p.add_argument("-o", "--out", "--output-dir", dest="out", required=True, help="output directory")
    p.add_argument("--workers", type=int, default=1, help="worker processes (each loads the model once)")
    p.add_argument("--engine", choices=("local", "ray"), default="local")
    p.add_argument("--ray-address", default=None, help="an existing Ray cluster (default: a local instance)")
    p.add_argument("--resume", action="store_true", help="continue the sweep in --out")
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("--no-pictures", action="store_true")
    p.add_argument("--export", choices=("openscenario",), default=None,
                   help="also write each scenario as OpenSCENARIO + OpenDRIVE (docs/openscenario.md)")
    p.add_argument("-v", "--verbose", action="store_true")
    o = p.parse_args(args)
    if o.workers < 1:
        p.error("--workers must be >= 1")
    o.parser = p
    return o


class SweepError(Exception):
    """Stops the sweep before it starts (exit 2, one line)."""


def prepare_out(o, spec, scenarios) -> list:
    """Check OUT (claimed by this process); returns the scenarios still to run (partial output of
    processes that died removed)."""
    from ..core.outputs import LOCK, clean_stale, partial_path
    plan_path = os.path.join(o.out, "sweep.json")
    if os.path.exists(plan_path):
        if not o.resume:
            raise SweepError(f"{o.out}: holds a sweep already (add --resume to continue it, or choose "
                             f"another --out)")
        with open(plan_path) as f:
            plan = json.load(f)
        if plan.get("digest") != spec.digest:
            raise SweepError(f"{o.spec}: differs from the spec {o.out} was started with "
                             f"({plan.get('spec')}); start a new --out")
    else:
        if [n for n in os.listdir(o.out) if n != LOCK and ".partial" not in n]:
            raise SweepError(f"{o.out}: exists and is not a sweep directory (choose another --out)")
        try:
            tmp = partial_path(plan_path)
            with open(tmp, "w") as f:
                json.dump({"spec": os.path.abspath(o.spec), "digest": spec.digest, "name": spec.name,
                           "scenarios": [s.params() for s in scenarios]}, f, indent=1)
            os.replace(tmp, plan_path)
        except OSError as e:
            raise SweepError(f"{o.out}: cannot write ({e.strerror or e})") from None
    from .worker import failure_path
    clean_stale(o.out)
    todo = []
    for s in scenarios:
        if os.path.isdir(os.path.join(o.out, s.id)):
            continue
        if os.path.exists(failure_path(o.out, s.id)):
            os.remove(failure_path(o.out, s.id))   # failed before: try again
        todo.append(s)
    return todo


def check_networks(source: str, spec, scenarios) -> None:
    """Each network entry a scenario uses, read as run reads its inputs (``Spec.scenario_of``) and
    loaded once by stock SUMO with its demand (sim/preflight.py) before any work: a scenario SUMO
    refuses stops the sweep in one line, not every worker."""
    from ..sim.preflight import preflight
    from ..sim.scenario import ScenarioError, meso_notice
    for name in dict.fromkeys(s.network for s in scenarios):
        scen = spec.scenario_of(name)
        if meso_notice(scen.config):
            print(f"{PROG}: warning: {meso_notice(scen.config)}", file=sys.stderr)
        try:
            preflight(scen)
        except ScenarioError as e:
            raise SweepError(f"{source}: network {name!r}: {e}") from None
        check_demand_times(source, name, spec.networks[name], scen)


def check_demand_times(source: str, name: str, entry, scen) -> None:
    """The entry's ``begin`` against its demand, as run checks ``--begin`` (data.demand.start_times),
    before any work; a route file cut short is warned about once (SUMO quits when its reading reaches the cut)."""
    from ..data.demand import DemandError, demand_files, start_times
    from ..map.network import Network, NetworkError
    demand = demand_files(scen.routes, scen.additional)
    if not demand:
        return
    try:
        net = Network.load(scen.net)
        _, _, span = start_times(scen, {ln.edge for ln in net.lanes}, entry.begin, demand, flag="begin")
    except (DemandError, NetworkError) as e:
        raise SweepError(f"{source}: network {name!r}: {e}") from None
    if span.cut is not None:
        print(f"{PROG}: warning: {span.cut.warning()}", file=sys.stderr)


def main(o) -> int:
    from ..core.outputs import OutputError, claim
    from ..export.opendrive import ExportError
    from ..tokens.file import TokenFileError
    from .spec import SpecError, load_spec
    t0 = time.perf_counter()
    try:
        spec = load_spec(o.spec)
        scenarios = spec.scenarios()
        check_networks(o.spec, spec, scenarios)
        with claim(o.out):
            return _sweep(o, spec, scenarios, t0)
    except (SpecError, TokenFileError, SweepError, OutputError, ExportError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")


def _sweep(o, spec, scenarios, t0) -> int:
    """Run the sweep as the owner of OUT."""
    from tqdm import tqdm

    from .engines import EngineError, run_local, run_ray, tasks
    from .index import contact_sheet, stats_plot, write_index
    todo = prepare_out(o, spec, scenarios)
    if todo:
        print(f"{spec.name}: {len(scenarios)} scenarios, {len(scenarios) - len(todo)} done before, "
              f"{len(todo)} to run on {o.workers} {o.engine} worker(s)", file=sys.stderr)
        bar = tqdm(total=len(scenarios), initial=len(scenarios) - len(todo), desc="scenarios",
                   unit=" scn", disable=not (sys.stderr.isatty() or o.verbose))
        batches = tasks(scenarios, {s.id for s in todo})
        try:
            if o.engine == "ray":
                run_ray(batches, spec, o.out, o.workers, o.checkpoint, bar, o.ray_address)
            else:
                run_local(batches, spec, o.out, o.workers, o.checkpoint, bar)
        except EngineError as e:
            o.parser.exit(2, f"{PROG}: error: {e}\n")
        finally:
            bar.close()
    # the workers of a sweep killed with SIGKILL die with it, but may not yet be gone when --resume
    # first looks: what they left is removed now, once this run's own writers are done
    from ..core.outputs import clean_stale
    clean_stale(o.out)
    rows = write_index(o.out, scenarios)
    if o.export:
        from ..export.batch import export_after
        export_after(o.out, [r["id"] for r in rows if r["status"] == "ok"], o.export,
                     workers=o.workers if o.engine == "local" else 1)
    pictures = [] if o.no_pictures else [contact_sheet(o.out, rows), stats_plot(o.out, rows)]
    ok = sum(r["status"] == "ok" for r in rows)
    failed = [r for r in rows if r["status"] == "failed"]
    print(f"{spec.name}: {ok} of {len(rows)} scenarios written to {o.out} in "
          f"{time.perf_counter() - t0:.1f} s; index.csv, index.jsonl"
          + "".join(f", {os.path.basename(p)}" for p in pictures if p))
    for r in failed[:10]:
        print(f"  failed {r['id']} ({r['network']}, {r['location']}): {r['error']}")
    if len(failed) > 10:
        print(f"  ... {len(failed) - 10} more failures (index.csv, column error)")
    return 0 if not failed else 1


if __name__ == "__main__":
    sys.exit(main(get_options()))
