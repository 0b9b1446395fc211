"""Record training scenes from SUMO traffic.

    python -m sumo_scendiff.data -n networks/grid3.net.xml -n networks/spider.net.xml \\
        -o data/train --scenes 20000 -s 0 --workers 2

Each network is simulated in several *episodes* (one SUMO run each, libsumo in-process); without
``--routes`` each episode gets random trips of a random insertion density (log-uniform over
``--density LO HI``, default 15-400 veh/h/km of lane) and a mixed fleet, so that scenes range from
empty to congested. Each scene holds every vehicle within the circle through its window's corners,
so that training can turn the window by any angle and still see all of it (``--square``: only the
window's square, as recordings before this option did). Output: ``DIR/manifest.json`` and
``DIR/shard-*.npz``. Work happens in ``DIR.partial`` and is renamed to ``DIR`` when complete; an
interrupted run (Ctrl-C, SIGTERM: exit 130, finished episodes kept) continues with ``--resume``.
The same seed gives the same scenes.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from contextlib import closing
from dataclasses import asdict, replace

from ..core.outputs import OutputError, claim
from ..core.procs import die_with_parent
from ..map.network import Network, NetworkError
from .demand import DemandError, check_routes
from .record import DENSITY, plan_episodes, record_shard_task
from .shards import DataError, Shard, net_entry, write_manifest

PROG = "python -m sumo_scendiff.data"


def get_options(args=None):
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-n", "--net-file", "--net", dest="nets", action="append", required=True,
                   metavar="NET", help="SUMO network (.net.xml[.gz]); repeat for several")
    p.add_argument("-r", "--routes", action="append", default=[], metavar="ROU",
                   help="the network's own demand (once per --net, in order); default: random trips")
    p.add_argument("-o", "--out", "--output-dir", dest="out", required=True, metavar="DIR")
    p.add_argument("--scenes", type=int, required=True, help="scenes to record in total")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("--scenes-per-episode", type=int, default=300)
    p.add_argument("--density", type=float, nargs=2, default=DENSITY, metavar=("LO", "HI"),
                   help="random trips: insertion density range, vehicles per hour per km of lane, drawn "
                        "log-uniformly per episode (default %(default)s)")
    p.add_argument("--square", action="store_true",
                   help="record only the window's square, not its circumscribed circle (turned "
                        "training windows then miss their corners; the format of older recordings)")
    p.add_argument("--workers", type=int, default=1, help="parallel SUMO processes")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in DIR.partial")
    p.add_argument("-v", "--verbose", action="store_true")
    o = p.parse_args(args)
    if o.scenes <= 0:
        p.error("--scenes must be positive")
    if not 0 < o.density[0] <= o.density[1]:
        p.error(f"--density {o.density[0]:g} {o.density[1]:g}: need 0 < LO <= HI")
    if o.routes and len(o.routes) != len(o.nets):
        p.error(f"give --routes once per --net ({len(o.nets)} nets, {len(o.routes)} route files)")
    o.parser = p
    return o


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # SIGTERM ends a recording as Ctrl-C does: finished episodes are kept


def _record_all(tasks: list[tuple], workers: int):
    """Record the episodes ``tasks`` (``record_shard``'s arguments), yielding each one's manifest
    entry as it finishes; with several workers, in spawn processes that die with this one."""
    if workers <= 1:
        yield from map(record_shard_task, tasks)
        return
    import multiprocessing as mp
    pool = mp.get_context("spawn").Pool(workers, initializer=die_with_parent, initargs=(os.getpid(),))
    try:
        yield from pool.imap_unordered(record_shard_task, tasks)
        pool.close()
    finally:
        pool.terminate()  # after an error or an interrupt: episodes in progress are dropped
        pool.join()


def main(o) -> int:
    out = os.path.abspath(o.out)
    try:  # one recording at a time owns DIR.partial, from the first check to the rename to DIR
        with claim(out + ".partial") as owner:
            return _record(o, out, owner)
    except OutputError as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")


def _record(o, out: str, owner) -> int:
    from tqdm import tqdm
    partial = owner.directory
    if os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)):
        o.parser.exit(2, f"{PROG}: error: {o.out}: exists and is not empty (choose another --out)\n")
    if not owner.created and not o.resume:
        o.parser.exit(2, f"{PROG}: error: {partial}: an interrupted run is there; "
                         f"continue it with --resume or remove it\n")
    try:
        nets = [Network.load(p) for p in o.nets]
        routes: list[str | None] = list(o.routes) or [None] * len(nets)
        begins = [0.0 if r is None else check_routes(r, {ln.edge for ln in n.lanes})
                  for n, r in zip(nets, routes)]
    except (NetworkError, DemandError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    names = [n.name for n in nets]
    if len(set(names)) != len(names):
        o.parser.exit(2, f"{PROG}: error: two networks share the name {names}: rename one\n")

    plan = plan_episodes(nets, [None if r is None else os.path.abspath(r) for r in routes], begins,
                         o.scenes, o.seed, o.scenes_per_episode, tuple(o.density), not o.square)
    config = {"nets": [os.path.abspath(p) for p in o.nets], "routes": routes, "scenes": o.scenes,
              "seed": o.seed, "scenes_per_episode": o.scenes_per_episode}
    if tuple(o.density) != DENSITY:  # (plans of runs started before the option stay resumable)
        config["density"] = list(o.density)
    if not o.square:
        config["disc"] = True
    plan_file = os.path.join(partial, "plan.json")
    if os.path.exists(plan_file):
        with open(plan_file) as f:
            if json.load(f) != config:
                o.parser.exit(2, f"{PROG}: error: {partial}: was started with other options; "
                                 f"remove it or repeat the original command\n")
    else:
        with open(plan_file, "w") as f:
            json.dump(config, f, indent=1)

    entries: dict[str, dict] = {}
    todo = []
    for k, name, spec in plan:
        path = os.path.join(partial, name)
        if os.path.exists(path):
            sh = Shard.load(path)
            entries[name] = {"file": name, "scenes": len(sh), "agents": int(sh.offsets[-1]), "net": k}
        else:
            todo.append((k, name, spec))
    for name in os.listdir(partial):  # an episode cut off while writing (the write is atomic)
        if name.endswith(".tmp.npz"):
            os.remove(os.path.join(partial, name))
    bar = tqdm(total=sum(s.scenes for _, _, s in plan), unit="scene", desc="recording",
               initial=sum(e["scenes"] for e in entries.values()), disable=None)
    on_sigterm = signal.signal(signal.SIGTERM, _interrupt)  # put back below (evaluate calls main)
    try:
        tasks = [(nets[k].path, spec, k, os.path.join(partial, name)) for k, name, spec in todo]
        with closing(_record_all(tasks, o.workers)) as finished:
            for entry in finished:
                entries[entry["file"]] = entry
                bar.update(entry["scenes"])
    except (DemandError, DataError) as e:
        bar.close()
        o.parser.exit(2, f"{PROG}: error: {e} (finished episodes are kept in {partial}; "
                         f"--resume continues)\n")
    except KeyboardInterrupt:
        bar.close()
        o.parser.exit(130, f"{PROG}: interrupted: {len(entries)} of {len(plan)} episodes are kept in "
                           f"{partial}; --resume continues\n")
    finally:
        signal.signal(signal.SIGTERM, on_sigterm)
    bar.close()

    episodes = [{"file": name, **asdict(replace(spec, routes=spec.routes and os.path.relpath(spec.routes, out)))}
                for _, name, spec in plan]
    manifest = write_manifest(partial, [net_entry(n.path, out, n.name) for n in nets],
                              [entries[name] for _, name, _ in plan], seed=o.seed, disc=not o.square,
                              episodes=episodes)
    os.remove(plan_file)
    if os.path.isdir(out):
        os.rmdir(out)  # exists but empty (checked above)
    owner.rename(out)
    print(f"{o.out}: {manifest['scenes']} scenes, {manifest['agents']} agents from "
          f"{len(nets)} network(s) in {len(plan)} episode(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
