"""A one-worker sweep runs its worker in a process of the pool, as more workers do: a native crash of
libsumo in it (here SIGSEGV, as a segfault on a state load) is survived, the task run again, and a
task whose worker dies every time is an error naming it; the sweep's own process lives on."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from .test_faults import _workers_of

pytestmark = pytest.mark.slow   # real sweeps of the CLI

SPEC = 'networks = ["{net}"]\nlocations = [{{auto = 2}}]\nseeds = 2\nrollout = 2.0\nsteps = 4\n'


def _base(cross_net, tmp_path) -> list[str]:
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(net=cross_net))
    return [sys.executable, "-m", "sumo_scendiff.sweep", "--spec", str(spec), "--no-pictures"]


def _in_a_task(pid: int) -> bool:
    """Whether worker ``pid`` has started SUMO (libsumo is loaded when a task's session starts)."""
    try:
        with open(f"/proc/{pid}/maps") as f:
            return "libsumo" in f.read()
    except OSError:   # gone already
        return False


def _crash_workers(sweep: subprocess.Popen, times: int) -> int:
    """Crash the sweep's worker processes (SIGSEGV) once each is running a task, ``times`` of them;
    returns how many were crashed before the sweep ended."""
    crashed: set[int] = set()
    deadline = time.time() + 600    # a guard against a hang, not a measurement
    while sweep.poll() is None and len(crashed) < times and time.time() < deadline:
        for pid in _workers_of(sweep.pid):
            if pid not in crashed and _in_a_task(pid):
                os.kill(pid, signal.SIGSEGV)
                crashed.add(pid)
        time.sleep(0.05)
    return len(crashed)


def _files(out) -> dict[str, bytes]:
    """Every file of a sweep but SUMO's states (their header holds the time they were written)."""
    return {os.path.relpath(os.path.join(d, n), out): open(os.path.join(d, n), "rb").read()
            for d, _, names in os.walk(out) for n in names if n != "state.xml.gz"}


def test_one_worker_survives_its_process_crashing(cross_net, tmp_path):
    """The crashed task runs again; the sweep writes byte for byte what an undisturbed sweep on two
    workers writes (the same seed, the same scenes, whatever the worker count)."""
    base = _base(cross_net, tmp_path)
    whole = subprocess.run([*base, "--workers", "2", "--out", str(tmp_path / "whole")], capture_output=True, text=True)
    assert whole.returncode == 0, whole.stderr
    out = tmp_path / "crashed"
    sweep = subprocess.Popen([*base, "--workers", "1", "--out", str(out)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    assert _crash_workers(sweep, 1) == 1, "the sweep ended before its worker could be crashed"
    _, err = sweep.communicate(timeout=600)
    assert sweep.returncode == 0, err
    got, want = _files(out), _files(tmp_path / "whole")
    assert sorted(got) == sorted(want) and got == want
    assert not list(out.glob("*.partial*")) and not list(out.glob("*.failed.json"))


def test_a_task_whose_one_worker_always_crashes_is_an_error_naming_it(cross_net, tmp_path):
    from sumo_scendiff.core.pool import TASK_TRIES
    out = tmp_path / "out"
    sweep = subprocess.Popen([*_base(cross_net, tmp_path), "--out", str(out)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    assert _crash_workers(sweep, TASK_TRIES) == TASK_TRIES
    _, err = sweep.communicate(timeout=600)
    last = err.strip().splitlines()[-1]
    assert sweep.returncode == 2 and "Traceback" not in err, err
    assert last.startswith("python -m sumo_scendiff.sweep: error: scenarios s00"), err
    assert f"its worker process died {TASK_TRIES} times" in last
    assert not (out / "index.csv").exists() and not list(out.glob("*.partial*"))
