"""A one-worker OpenSCENARIO export replays in a process of the pool, as more workers do: a native crash
of libsumo in it (here SIGSEGV) is survived and the folder replayed again, writing what an undisturbed
export writes; a folder whose worker dies every time is one line naming it (exit 2), the caller's own
output kept (real SUMO, libsumo; the sweep's with the shipped model)."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from sumo_scendiff.core.pool import TASK_TRIES

from .test_openscenario import _seeded_copies, cache, folder  # noqa: F401  (fixtures: a scene folder, a cache)
from .test_sweep_engines import _crash_workers

pytestmark = pytest.mark.slow   # real replays in spawned processes

SEEDS = (0, 7, 23, 41)   # folders of one network: one SUMO replays them in turn (export.replay.Replayer)


def _export(folders, cache, **popen) -> subprocess.Popen:
    env = {**os.environ, "XDG_CACHE_HOME": cache}
    return subprocess.Popen([sys.executable, "-m", "sumo_scendiff.export", *folders, "--force"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **popen)


def test_one_worker_export_survives_its_process_crashing(folder, cache, tmp_path):
    calm = _seeded_copies(folder, tmp_path / "calm", SEEDS)
    done = _export(calm, cache)
    _, err = done.communicate(timeout=600)
    assert done.returncode == 0, err
    crashed = _seeded_copies(folder, tmp_path / "crashed", SEEDS)
    export = _export(crashed, cache)
    assert _crash_workers(export, 1) == 1, "the export ended before its worker could be crashed"
    _, err = export.communicate(timeout=600)
    assert export.returncode == 0, err
    for a, b in zip(calm, crashed):
        for name in ("scenario.xosc", "scenario.xodr"):
            with open(os.path.join(a, name), "rb") as x, open(os.path.join(b, name), "rb") as y:
                assert x.read() == y.read(), (b, name)
        assert os.path.isfile(os.path.join(b, "openscenario.json"))
    assert not [p for f in crashed for p in os.listdir(f) if "partial" in p]


SPEC = 'networks = ["{net}"]\nlocations = [{{auto = 1}}]\nseeds = 1\nrollout = 2.0\nsteps = 4\n'


def test_a_sweep_export_whose_one_worker_always_crashes_is_one_line(cross_net, tmp_path):
    """The sweep's scenes and index stay; the export's worker is crashed each time it replays."""
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(net=cross_net))
    out = tmp_path / "out"
    sweep = subprocess.Popen([sys.executable, "-m", "sumo_scendiff.sweep", "--spec", str(spec), "--out", str(out),
                              "--no-pictures", "--export", "openscenario"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 600     # a guard against a hang, not a measurement
    while sweep.poll() is None and not (out / "index.csv").exists() and time.time() < deadline:
        time.sleep(0.05)             # the sweep's own workers are gone once its index is written
    assert _crash_workers(sweep, TASK_TRIES) == TASK_TRIES
    _, err = sweep.communicate(timeout=600)
    last = err.strip().splitlines()[-1]
    assert sweep.returncode == 2 and "Traceback" not in err, err
    assert last.startswith(f"python -m sumo_scendiff.sweep: error: {out / 's0000'}: "), err
    assert f"its worker process died {TASK_TRIES} times" in last
    assert (out / "index.csv").exists() and (out / "s0000" / "scene.json").exists()
    assert not (out / "s0000" / "openscenario.json").exists()
