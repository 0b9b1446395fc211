"""Export finished scene folders (run, sweeps, the fill) as ASAM OpenSCENARIO 1.2 + OpenDRIVE.

    python -m sumo_scendiff.export out/scene_000 --format openscenario
    python -m sumo_scendiff.export sweeps/truck/s* --format openscenario --force

Beside each folder's SUMO files: ``scenario.xodr`` (netconvert's OpenDRIVE of its network, converted
once per network), ``scenario.xosc`` (validated against the ASAM schema scenariogeneration ships) and
``openscenario.json`` (offset, validation, timing). docs/openscenario.md says how to play them in
esmini and CARLA ScenarioRunner. A folder that cannot be exported: one line, exit 2; folders before
it are complete, nothing of it is left half-written.
"""
from __future__ import annotations

import argparse
import sys

PROG = "python -m sumo_scendiff.export"


def get_options(args=None):
    from ..core.cli import HelpFormatter, description, epilog
    from .batch import FORMATS
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), epilog=epilog(__doc__),
                                formatter_class=HelpFormatter)
    p.add_argument("folders", nargs="+", metavar="DIR", help="scene folders (holding scene.json or fill.json)")
    p.add_argument("--format", default="openscenario", choices=FORMATS)
    p.add_argument("--seconds", type=float, default=None,
                   help="seconds of SUMO's drive to record (default: the folder's rollout; 0: none)")
    p.add_argument("--force", action="store_true", help="replace an earlier export in the folders")
    p.add_argument("--workers", type=int, default=1, help="local processes, each replaying in its own libsumo")
    p.add_argument("-v", "--verbose", action="store_true")
    o = p.parse_args(args)
    if o.workers < 1:
        p.error(f"--workers must be >= 1, got {o.workers}")
    if o.seconds is not None and not o.seconds >= 0:
        p.error(f"--seconds must be >= 0, got {o.seconds}")
    o.parser = p
    return o


def main(o) -> int:
    from ..core.pool import EngineError
    from .batch import export_folders
    from .opendrive import ExportError
    try:
        s = export_folders(o.folders, o.format, force=o.force, seconds=o.seconds,
                           progress=sys.stderr.isatty() or o.verbose, workers=o.workers)
    except (ExportError, EngineError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    print(f"exported {s['exported']} folders ({s['vehicles']} vehicles) in {s['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
