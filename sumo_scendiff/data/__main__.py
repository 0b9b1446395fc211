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
import sys

from ..core.outputs import OutputError
from .record import DENSITY
from .recording import RecordingError, RecordingInterrupted, record_dataset

PROG = "python -m sumo_scendiff.data"


def get_options(args=None):
    from ..core.cli import HelpFormatter, description
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), formatter_class=HelpFormatter)
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


def main(o) -> int:
    try:
        manifest = record_dataset(o.nets, o.out, o.scenes, o.seed, routes=o.routes or None,
                                  per_episode=o.scenes_per_episode, density=tuple(o.density),
                                  disc=not o.square, workers=o.workers, resume=o.resume)
    except (RecordingError, OutputError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    except RecordingInterrupted as e:
        o.parser.exit(130, f"{PROG}: interrupted: {e}\n")
    print(f"{o.out}: {manifest['scenes']} scenes, {manifest['agents']} agents from "
          f"{len(manifest['nets'])} network(s) in {len(manifest['episodes'])} episode(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
