"""Faults from outside: a disk that fills up mid-run, a read-only output folder, a SUMO killed in
the middle. Each ends in one line naming the folder (or SUMO's last words), exit 2, nothing left
that looks complete when it is not, and `--resume` continuing from what is complete."""
from __future__ import annotations

import contextlib
import gzip
import os
import subprocess
import sys

import pytest

from sumo_scendiff.sim.export import FILES


def _mount(path, options: str) -> None:
    path.mkdir(exist_ok=True)
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"a small file system cannot be mounted here ({p.stderr.strip() or 'mount failed'})")


@contextlib.contextmanager
def _tmpfs(path, options: str):
    _mount(path, options)
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


@pytest.fixture(scope="module")
def grid_net(tmp_path_factory) -> str:
    import sumo
    out = str(tmp_path_factory.mktemp("faults") / "grid.net.xml")
    subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "netgenerate"), "--grid", "--grid.number", "3",
                    "--grid.length", "100", "-o", out], check=True, capture_output=True)
    return out


def _cli(command: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", f"sumo_scendiff.{command}", *args], capture_output=True, text=True)


def _one_line(p: subprocess.CompletedProcess, *words: str) -> str:
    """Exit 2 and one error line, the last (a sweep says what it starts before), naming ``words``."""
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if "error:" in ln]
    assert p.returncode == 2 and errors == lines[-1:] and "Traceback" not in p.stderr, p.stderr
    assert all(w in lines[-1] for w in words), lines[-1]
    return lines[-1]


def _complete(scene) -> bool:
    """Every file of a scene folder there and whole (the state and picture read to their end)."""
    import cv2
    if not all((scene / f).is_file() for f in FILES):
        return False
    with gzip.open(scene / "state.xml.gz") as f:
        f.read()
    return cv2.imread(str(scene / "scene.png")) is not None


@pytest.mark.slow    # two runs of the CLI
def test_a_disk_that_fills_up_mid_run(grid_net, tmp_path):
    with _tmpfs(tmp_path / "small", "size=600k") as mnt:
        out = mnt / "out"
        args = ["-n", grid_net, "--scenes", "12", "--rollout", "0", "-o", str(out)]
        _one_line(_cli("run", *args), str(out), "No space left")
        names = sorted(os.listdir(out))
        scenes = [n for n in names if n.startswith("scene_")]
        assert 0 < len(scenes) < 12 and all(_complete(out / n) for n in scenes), names
        assert not [n for n in names if ".partial" in n] and "run.json" not in names, names
        before = {n: (out / n / "scene.json").stat().st_mtime_ns for n in scenes}
        subprocess.run(["mount", "-o", "remount,size=8m", str(mnt)], check=True)
        p = _cli("run", *args, "--resume")
        assert p.returncode == 0, p.stderr
        assert all(_complete(out / f"scene_{k:03d}") for k in range(12))
        assert before == {n: (out / n / "scene.json").stat().st_mtime_ns for n in scenes}   # kept


@pytest.mark.slow
@pytest.mark.parametrize("size", ["100k", "150k"])   # full at randomTrips' output; at duarouter's, which exits 0
def test_a_fill_on_a_full_disk_leaves_no_complete_looking_folder(grid_net, tmp_path, size):
    with _tmpfs(tmp_path / "small", f"size={size}") as mnt:
        out = mnt / "filled"
        _one_line(_cli("fill", "-n", grid_net, "-o", str(out)), str(out), "No space left")
        assert os.listdir(mnt) == []


@pytest.mark.parametrize("command", ["run", "fill"])
def test_a_read_only_output_folder(grid_net, tmp_path, command):
    with _tmpfs(tmp_path / "ro", "ro,size=64k") as mnt:
        out = mnt / "out"
        _one_line(_cli(command, "-n", grid_net, "-o", str(out)), f"{out}:", "Read-only")
        assert os.listdir(mnt) == []


def _sumo_of(pid: int) -> int | None:
    """The SUMO process a process started (its child), or None."""
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as f:
            for child in f.read().split():
                with open(f"/proc/{child}/cmdline", "rb") as c:
                    if os.path.basename(c.read().split(b"\0")[0]) == b"sumo":
                        return int(child)
    return None


@pytest.mark.slow    # three runs of the CLI
def test_a_killed_sumo_ends_the_run_in_one_line_and_resume_continues(grid_net, tmp_path):
    import signal
    import time
    out = tmp_path / "out"
    args = ["-n", grid_net, "--traci", "--scenes", "3", "--rollout", "3000", "-o", str(out)]
    run = subprocess.Popen([sys.executable, "-m", "sumo_scendiff.run", *args], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    sumo, seen = None, {}
    while run.poll() is None and sumo is None:     # a SUMO of a later scene, running a second by now
        time.sleep(0.05)
        child = _sumo_of(run.pid) if (out / "scene_000").is_dir() else None
        if child is not None and time.monotonic() - seen.setdefault(child, time.monotonic()) > 1.0:
            sumo = child
    assert sumo is not None, "the run ended before its SUMO could be killed"
    os.kill(sumo, signal.SIGKILL)
    _, err = run.communicate(timeout=60)
    line = _one_line(subprocess.CompletedProcess(run.args, run.returncode, "", err), "SIGKILL", f"process {sumo}")
    assert "ended in the middle" in line
    names = sorted(os.listdir(out))
    assert names[0] == "scene_000" and _complete(out / "scene_000")
    assert not [n for n in names if n != "scene_000" and not n.startswith(".")], names   # no partial, no run.json
    kept = (out / "scene_000" / "scene.json").read_bytes()
    p = _cli("run", *args, "--resume")
    assert p.returncode == 0, p.stderr
    assert all(_complete(out / f"scene_{k:03d}") for k in range(3))
    assert (out / "scene_000" / "scene.json").read_bytes() == kept
    whole = tmp_path / "whole"           # the same run undisturbed: the resumed scenes are its scenes
    assert _cli("run", *args[:-1], str(whole)).returncode == 0
    for k in (1, 2):
        assert (out / f"scene_{k:03d}" / "scenario.rou.xml").read_bytes() == \
            (whole / f"scene_{k:03d}" / "scenario.rou.xml").read_bytes()


def test_the_cosimulation_raises_sumo_died(grid_net, gen):
    """The caller's own traci SUMO killed between two seedings: the next call raises SumoDied (one
    line, how SUMO ended), which a caller catches by name."""
    import signal

    import traci

    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.cosim import CoSimulation
    from sumo_scendiff.sim.sumo import SimError, SumoDied, sumo_binary
    traci.start([sumo_binary("sumo"), "-n", grid_net, "--no-step-log"], label="faults")
    try:
        traci.route.add("r", ["A0B0", "B0C0"])
        traci.vehicle.add("ego", "r", departSpeed="5")
        traci.simulationStep()
        cosim = CoSimulation(traci, Network.load(grid_net), gen)
        cosim.seed_around("ego", p_mask=1.0)
        os.kill(traci.getConnection("faults")._process.pid, signal.SIGKILL)
        with pytest.raises(SumoDied) as caught:
            cosim.seed_around("ego", p_mask=1.0)
        assert isinstance(caught.value, SimError) and "\n" not in str(caught.value)
        assert "SIGKILL" in str(caught.value)
    finally:
        with contextlib.suppress(Exception):
            traci.close()


@pytest.mark.slow
def test_a_sweep_on_a_full_disk_resumes_where_it_stopped(grid_net, tmp_path):
    """The scenarios the disk refused are failures the sweep names; the sweep ends in one line naming
    its folder, and --resume with room runs them again (the index then complete)."""
    spec = tmp_path / "spec.toml"
    spec.write_text(f'networks = ["{grid_net}"]\nlocations = [{{auto = 1}}]\nseeds = 8\nrollout = 0.0\n')
    with _tmpfs(tmp_path / "small", "size=400k") as mnt:
        out = mnt / "out"
        args = ["--spec", str(spec), "--out", str(out)]
        _one_line(_cli("sweep", *args), str(out), "No space left")
        assert not [n for n in os.listdir(out) if n.startswith("s0") and ".partial" in n]
        subprocess.run(["mount", "-o", "remount,size=8m", str(mnt)], check=True)
        p = _cli("sweep", *args, "--resume")
        assert p.returncode == 0, p.stderr
        assert sorted(n for n in os.listdir(out) if n.startswith("s0")) == [f"s{k:04d}" for k in range(8)]
        assert (out / "contact_sheet.png").is_file() and not list(out.glob("*.partial*"))


class Dying:
    """A worker whose process dies (SIGKILL) on the tasks it is told to, as often as told."""

    def __init__(self, folder: str):
        self.folder = folder

    def run(self, k: int, deaths: int) -> int:
        import signal
        marks = [n for n in os.listdir(self.folder) if n.startswith(f"{k}.")]
        if len(marks) < deaths:
            open(os.path.join(self.folder, f"{k}.{len(marks)}"), "w").close()
            os.kill(os.getpid(), signal.SIGKILL)
        return k * k


def test_a_killed_worker_s_task_runs_again(tmp_path):
    """Task 3's worker killed twice: its task and those running beside it run again, every result
    once; a task whose worker dies three times is an error naming it."""
    from sumo_scendiff.core.pool import TASK_TRIES, EngineError, LocalPool
    with LocalPool(Dying, (str(tmp_path),), workers=2) as pool:
        got = list(pool.map_unordered([(k, 2 if k == 3 else 0) for k in range(8)]))
    assert sorted(got) == [(k, k * k) for k in range(8)]
    with pytest.raises(EngineError, match=rf"tile 5: its worker process died {TASK_TRIES} times"):
        with LocalPool(Dying, (str(tmp_path),), workers=2) as pool:
            list(pool.map_unordered([(k, 9 if k == 5 else 0) for k in range(4, 7)], name=lambda t: f"tile {t[0]}"))


def _workers_of(pid: int) -> list[int]:
    """The worker processes multiprocessing spawned for process ``pid`` (not its resource tracker)."""
    out = []
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as f:
            for child in map(int, f.read().split()):
                with open(f"/proc/{child}/cmdline", "rb") as c:
                    if b"spawn_main" in c.read():
                        out.append(child)
    return out


@pytest.mark.slow    # two sweeps of two workers
def test_a_sweep_whose_worker_is_killed_writes_what_an_undisturbed_one_does(grid_net, tmp_path):
    import signal
    import time
    spec = tmp_path / "spec.toml"
    spec.write_text(f'networks = ["{grid_net}"]\nlocations = [{{auto = 2}}]\nseeds = 4\nrollout = 5.0\n')
    base = ["--spec", str(spec), "--workers", "2", "--no-pictures"]
    assert _cli("sweep", *base, "--out", str(tmp_path / "whole")).returncode == 0
    out = tmp_path / "killed"
    sweep = subprocess.Popen([sys.executable, "-m", "sumo_scendiff.sweep", *base, "--out", str(out)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    victim = None
    while sweep.poll() is None and victim is None:   # a worker, once the first scenario is written
        time.sleep(0.05)
        written = out.is_dir() and any(n.startswith("s0") and "." not in n for n in os.listdir(out))
        victim = next(iter(_workers_of(sweep.pid)), None) if written else None
    assert victim is not None, "the sweep ended before a worker could be killed"
    os.kill(victim, signal.SIGKILL)
    _, err = sweep.communicate(timeout=600)
    assert sweep.returncode == 0, err
    for name in ("index.csv", "index.jsonl"):
        assert (out / name).read_text() == (tmp_path / "whole" / name).read_text()
    assert not list(out.glob("*.partial*")) and not list(out.glob("*.failed.json"))


@pytest.mark.slow    # a local Ray instance
def test_a_killed_ray_actor_s_task_runs_again(tmp_path):
    pytest.importorskip("ray")
    from sumo_scendiff.core.pool import TASK_TRIES, EngineError, RayPool
    with RayPool(Dying, (str(tmp_path),), workers=2, address="local") as pool:
        got = list(pool.map_unordered([(k, 2 if k == 3 else 0) for k in range(8)]))
        assert sorted(got) == [(k, k * k) for k in range(8)]
        with pytest.raises(EngineError, match=rf"tile 9: the Ray actor running it died {TASK_TRIES} times"):
            list(pool.map_unordered([(9, 9)], name=lambda t: f"tile {t[0]}"))
