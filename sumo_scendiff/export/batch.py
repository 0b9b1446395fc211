"""Many scene folders exported (the network's OpenDRIVE converted once, the schema read once per
process) on ``workers`` local processes, each replaying in its own libsumo: what
``python -m sumo_scendiff.export`` and the ``--export`` flags of ``run``, sweeps and the fill call.
A single worker is a process of the pool too, not the caller's: a native crash of libsumo in a replay
kills a worker the pool replaces and runs the folder again (core.pool), not the caller with its
output; a folder whose worker dies every time is an ExportError naming it."""
from __future__ import annotations

import os
import sys
import time

from .opendrive import ExportError, opendrive_for
from .openscenario import FILES, export_folder, read_folder
from .replay import Replayer

FORMATS = ("openscenario",)


class Exporter:
    """A pool worker (core.pool): one folder per task, replayed in one SUMO per network (replay.Replayer)."""

    def __init__(self, force: bool = False, seconds: float | None = None, share: bool = True):
        self.force, self.seconds = force, seconds
        self.replayer = Replayer(share)   # share: more than one folder to come (a single one: no second start)

    def run(self, folder: str) -> dict:
        return export_folder(folder, force=self.force, seconds=self.seconds, replayer=self.replayer)

    def close(self) -> None:
        self.replayer.close()


def _networks_first(folders: list[str]) -> None:
    """Convert each network once here, before workers would each convert it."""
    from ..sim.scenario import ScenarioError, read_sumocfg
    for folder in folders:
        _, config = read_folder(folder)
        try:
            opendrive_for(read_sumocfg(config)["net"])
        except (ScenarioError, KeyError):
            pass            # the folder's own export says what is wrong with it


def export_folders(folders: list[str], fmt: str = "openscenario", force: bool = False,
                   seconds: float | None = None, keep_done: bool = False, progress: bool = False,
                   workers: int = 1) -> dict:
    """Export each folder; ``keep_done``: a folder whose export is complete (its openscenario.json
    exists, as a resumed run's kept scenes) is left as it is. Raises ExportError on a folder that
    cannot be exported (the others finished by then are complete)."""
    from tqdm import tqdm

    from ..core.pool import EngineError, LocalPool
    if fmt not in FORMATS:
        raise ExportError(f"--format: {fmt!r} is not one of {', '.join(FORMATS)}")
    t0 = time.perf_counter()
    todo = [f for f in folders if not (keep_done and os.path.isfile(os.path.join(f, FILES[-1])))]
    if not todo:   # nothing to replay: no process to start
        return {"exported": 0, "kept": len(folders), "vehicles": 0, "seconds": round(time.perf_counter() - t0, 3)}
    vehicles, workers = 0, max(1, min(workers, len(todo)))
    if workers > 1:
        _networks_first(todo)
    try:
        with LocalPool(Exporter, (force, seconds, len(todo) > workers), workers=workers) as pool, \
                tqdm(total=len(todo), desc="exporting OpenSCENARIO", disable=not progress, leave=False) as bar:
            for _, record in pool.map_unordered([(f,) for f in todo], name=lambda task: task[0]):
                vehicles += record["vehicles"]
                bar.update()
    except EngineError as e:   # a replay that crashed its SUMO every time (or a worker that cannot start)
        raise ExportError(str(e)) from None
    return {"exported": len(todo), "kept": len(folders) - len(todo), "vehicles": vehicles,
            "seconds": round(time.perf_counter() - t0, 3)}


def export_after(out: str, names: list[str], fmt: str, workers: int = 1) -> None:
    """The ``--export`` of a run, sweep or fill: its finished folders ``out/name``, one line on stderr."""
    folders = [os.path.join(out, n) for n in names if os.path.isdir(os.path.join(out, n))]
    # the command's own folders: an export interrupted before its openscenario.json is redone
    s = export_folders(folders, fmt, force=True, keep_done=True, progress=sys.stderr.isatty(), workers=workers)
    print(f"exported {s['exported']} folders as OpenSCENARIO 1.2 + OpenDRIVE ({s['vehicles']} vehicles, "
          f"{s['seconds']:.1f} s)" + (f"; {s['kept']} exported before" if s["kept"] else ""), file=sys.stderr)
