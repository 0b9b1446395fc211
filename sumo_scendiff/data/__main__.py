"""Record training scenes from SUMO traffic.

    python -m sumo_scendiff.data -n networks/grid3.net.xml -n networks/spider.net.xml \\
        -o data/train --scenes 20000 -s 0 --workers 2

Each network is simulated in several *episodes* (one SUMO run each, libsumo in-process); without
``--routes`` each episode gets random trips of a random insertion density (log-uniform over
``--density LO HI``, default 15-400 veh/h/km of lane) and a mixed fleet, so that scenes range from
empty to congested; ``--peak-share P`` gives that share of the episodes peak-hour demand
(``--peak-density``), ``--default-sizes S`` puts that share of the fleet in SUMO's own vTypes (the
sizes of scenarios that define none). Each scene holds every vehicle within the circle through its
window's corners, so that training can turn the window by any angle and still see all of it
(``--square``: only the window's square, as recordings before this option did). Output:
``DIR/manifest.json`` and ``DIR/shard-*.npz``. Work happens in ``DIR.partial`` and is renamed to
``DIR`` when complete; an interrupted run (Ctrl-C, SIGTERM: exit 130, finished episodes kept)
continues with ``--resume``. The same seed gives the same scenes.
"""
from __future__ import annotations

import argparse
import sys

from ..core.outputs import OutputError
from .record import DENSITY, PEAK_DENSITY
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
    p.add_argument("--peak-share", type=float, default=0.0, metavar="P",
                   help="random trips: the share of episodes with peak-hour demand, their density drawn "
                        "log-uniformly from --peak-density instead (default %(default)s: none)")
    p.add_argument("--peak-density", type=float, nargs=2, default=PEAK_DENSITY, metavar=("LO", "HI"),
                   help="random trips: the peak episodes' density range, vehicles per hour per km of "
                        "lane (default %(default)s)")
    p.add_argument("--default-sizes", type=float, default=0.0, metavar="SHARE",
                   help="random trips: the share of each vehicle class in SUMO's own vType of that "
                        "class (SUMO's default sizes: a passenger car 5 m x 1.8 m) instead of the "
                        "fleet's sized types (default %(default)s)")
    p.add_argument("--square", action="store_true",
                   help="record only the window's square, not its circumscribed circle (turned "
                        "training windows then miss their corners; the format of older recordings)")
    p.add_argument("--workers", type=int, default=1, help="parallel SUMO processes")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in DIR.partial")
    p.add_argument("-v", "--verbose", action="store_true")
    o = p.parse_args(args)
    if o.scenes <= 0:
        p.error("--scenes must be positive")
    for flag, (lo, hi) in (("--density", o.density), ("--peak-density", o.peak_density)):
        if not 0 < lo <= hi:
            p.error(f"{flag} {lo:g} {hi:g}: need 0 < LO <= HI")
    for flag, share in (("--peak-share", o.peak_share), ("--default-sizes", o.default_sizes)):
        if not 0 <= share <= 1:
            p.error(f"{flag} {share:g}: need a share in [0, 1]")
    if o.routes and len(o.routes) != len(o.nets):
        p.error(f"give --routes once per --net ({len(o.nets)} nets, {len(o.routes)} route files)")
    o.parser = p
    return o


def main(o) -> int:
    try:
        manifest = record_dataset(o.nets, o.out, o.scenes, o.seed, routes=o.routes or None,
                                  per_episode=o.scenes_per_episode, density=tuple(o.density),
                                  disc=not o.square, workers=o.workers, resume=o.resume,
                                  default_sizes=o.default_sizes, peak_share=o.peak_share,
                                  peak_density=tuple(o.peak_density))
    except (RecordingError, OutputError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    except RecordingInterrupted as e:
        o.parser.exit(130, f"{PROG}: interrupted: {e}\n")
    print(f"{o.out}: {manifest['scenes']} scenes, {manifest['agents']} agents from "
          f"{len(manifest['nets'])} network(s) in {len(manifest['episodes'])} episode(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
