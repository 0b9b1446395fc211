"""Many scene folders exported in one process (the network's OpenDRIVE converted once, the schema
read once): what ``python -m sumo_scendiff.export`` and the ``--export`` flags of ``run``, sweeps
and the fill call."""
from __future__ import annotations

import os
import sys
import time

from .openscenario import FILES, export_folder
from .opendrive import ExportError

FORMATS = ("openscenario",)


def export_folders(folders: list[str], fmt: str = "openscenario", force: bool = False,
                   seconds: float | None = None, keep_done: bool = False, progress: bool = False) -> dict:
    """Export each folder; ``keep_done``: a folder whose export is complete (its openscenario.json
    exists, as a resumed run's kept scenes) is left as it is. Raises ExportError on the first
    folder that cannot be exported (those before it are complete)."""
    if fmt not in FORMATS:
        raise ExportError(f"--format: {fmt!r} is not one of {', '.join(FORMATS)}")
    from tqdm import tqdm
    t0, done, kept, vehicles = time.perf_counter(), 0, 0, 0
    for folder in tqdm(folders, desc="exporting OpenSCENARIO", disable=not progress, leave=False):
        if keep_done and os.path.isfile(os.path.join(folder, FILES[-1])):
            kept += 1
            continue
        record = export_folder(folder, force=force, seconds=seconds)
        done, vehicles = done + 1, vehicles + record["vehicles"]
    return {"exported": done, "kept": kept, "vehicles": vehicles, "seconds": round(time.perf_counter() - t0, 3)}


def export_after(out: str, names: list[str], fmt: str) -> None:
    """The ``--export`` of a run, sweep or fill: its finished folders ``out/name``, one line on stderr."""
    folders = [os.path.join(out, n) for n in names if os.path.isdir(os.path.join(out, n))]
    s = export_folders(folders, fmt, keep_done=True, progress=sys.stderr.isatty())
    print(f"exported {s['exported']} folders as OpenSCENARIO 1.2 + OpenDRIVE ({s['vehicles']} vehicles, "
          f"{s['seconds']:.1f} s)" + (f"; {s['kept']} exported before" if s["kept"] else ""), file=sys.stderr)
