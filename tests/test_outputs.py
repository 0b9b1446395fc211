"""One output directory, one owner: real processes racing for, killed in and resuming one -o."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest

from sumo_scendiff.core.outputs import (
    LOCK,
    OutputBusy,
    claim,
    clean_stale,
    partial_path,
)
from sumo_scendiff.sim.export import FILES

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CITY = os.path.join(ROOT, "networks", "city.net.xml")
RUN = [sys.executable, "-m", "sumo_scendiff.run", "-n", CITY, "--scenes", "3", "-s", "2"]
# long enough per scene that a scene in progress can be caught, short enough for a test
SLOW = ["--rollout", "150", "--step-length", "0.1"]
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}
HOLD = ("import sys, time; from sumo_scendiff.core.outputs import claim\n"
        "with claim(sys.argv[1]):\n    print('held', flush=True); time.sleep(120)\n")


def _holder(directory):
    """Another process that owns ``directory`` until it is killed."""
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(directory)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


def _start(out, *extra):
    return subprocess.Popen(RUN + SLOW + ["-o", str(out), *extra], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV, start_new_session=True)


def _wait_for(path, proc, seconds=60):
    deadline = time.time() + seconds
    while not os.path.isdir(path):
        assert proc.poll() is None and time.time() < deadline, "the run ended before " + str(path)
        time.sleep(0.01)


def _scenes(out) -> dict[str, tuple[bytes, bytes]]:
    return {d: (open(os.path.join(out, d, "scene.json"), "rb").read(),
                open(os.path.join(out, d, "scenario.rou.xml"), "rb").read())
            for d in sorted(os.listdir(out)) if d.startswith("scene_")}


def _rows(out) -> list[dict]:
    with open(os.path.join(out, "run.json")) as f:
        return json.load(f)["scenes"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole") / "out"
    res = subprocess.run(RUN + SLOW + ["-o", str(out)], check=False, capture_output=True, text=True, env=ENV, timeout=120)
    assert res.returncode == 0, res.stderr
    return out


def test_claim_names_the_owner_and_dies_with_it(tmp_path):
    d = tmp_path / "out"
    p = _holder(d)
    try:
        with pytest.raises(OutputBusy, match=re.escape(f"{d}: in use by process {p.pid},")), claim(str(d)):
            pass
    finally:
        p.kill()                     # SIGKILL: no clean-up runs, the lock file stays
        p.wait()
    assert (d / LOCK).read_text().strip() == str(p.pid)
    with claim(str(d)) as owner:     # the kernel dropped the dead process's lock
        assert (d / LOCK).read_text().strip() == str(os.getpid()) and not owner.created
    assert not (d / LOCK).exists()
    with claim(str(tmp_path / "fresh")):
        pass
    assert not (tmp_path / "fresh").exists(), "a claimed directory nobody wrote into is left behind"


def test_only_partials_of_dead_processes_are_cleaned(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          check=False, capture_output=True, text=True).stdout.strip()
    mine = partial_path(str(tmp_path / "scene_000"))
    for name in (f"scene_001.partial-{dead}", "scene_002.partial", f"other.partial-{dead}", "keep.txt"):
        (tmp_path / name).mkdir() if name.startswith("scene") else (tmp_path / name).write_text("x")
    os.mkdir(mine)
    removed = clean_stale(str(tmp_path), {"scene_000", "scene_001", "scene_002"})
    assert removed == [f"scene_001.partial-{dead}", "scene_002.partial"]
    assert sorted(os.listdir(tmp_path)) == sorted([os.path.basename(mine), f"other.partial-{dead}", "keep.txt"])


def test_the_partial_of_a_dead_writer_not_yet_reaped_is_cleaned(tmp_path):
    # a worker killed with its parent is a zombie until reaped: it writes nothing any more
    zombie = subprocess.Popen([sys.executable, "-c", "pass"])
    deadline = time.time() + 30
    while time.time() < deadline:
        with open(f"/proc/{zombie.pid}/stat") as f:
            if f.read().rpartition(")")[2].split()[0] == "Z":
                break
        time.sleep(0.05)
    (tmp_path / f"scene_000.partial-{zombie.pid}").mkdir()
    try:
        assert clean_stale(str(tmp_path)) == [f"scene_000.partial-{zombie.pid}"]
    finally:
        zombie.wait()


def test_two_runs_into_one_directory(tmp_path):
    out = tmp_path / "out"
    a, b = _start(out), _start(out)
    (_, err_a), (_, err_b) = a.communicate(timeout=120), b.communicate(timeout=120)
    codes = sorted([a.returncode, b.returncode])
    assert codes == [0, 2], (err_a, err_b)
    winner, loser_err = (a, err_b) if a.returncode == 0 else (b, err_a)
    assert loser_err.strip() == (f"python -m sumo_scendiff.run: error: {out}: in use by process {winner.pid}, "
                                 f"which writes there now (wait for it to end or choose another output "
                                 f"directory)")
    assert sorted(os.listdir(out)) == ["run.json", "scene_000", "scene_001", "scene_002"]
    for k in range(3):
        assert sorted(os.listdir(out / f"scene_{k:03d}")) == sorted(FILES + ("city.net.xml.gz",))


def test_sigkill_then_resume_equals_an_uninterrupted_run(uninterrupted, tmp_path):
    out = tmp_path / "out"
    p = _start(out)
    _wait_for(out / "scene_000", p)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate()
    done = [d for d in os.listdir(out) if d.startswith("scene_") and ".partial" not in d]
    assert 1 <= len(done) < 3, done
    assert (out / LOCK).read_text().strip() == str(p.pid)   # left by the dead run: must not block

    res = subprocess.run(RUN + SLOW + ["-o", str(out)], check=False, capture_output=True, text=True, env=ENV, timeout=60)
    assert res.returncode == 2 and "scene_000: exists" in res.stderr and "--resume" in res.stderr
    res = subprocess.run(RUN + SLOW + ["-o", str(out), "--resume"], check=False, capture_output=True, text=True, env=ENV,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    assert sorted(os.listdir(out)) == ["run.json", "scene_000", "scene_001", "scene_002"]
    assert _scenes(out) == _scenes(uninterrupted)
    assert _rows(out) == _rows(uninterrupted)


def test_sigterm_exits_130_with_the_resume_hint(tmp_path):
    out = tmp_path / "out"
    p = _start(out)
    _wait_for(out / "scene_000", p)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err and last.startswith("python -m sumo_scendiff.run: interrupted: ")
    assert last.endswith("rerun with --resume to write the others") and str(out) in last
    names = os.listdir(out)
    assert "scene_000" in names and "run.json" not in names and LOCK not in names
    assert not [n for n in names if ".partial" in n], names


@pytest.mark.parametrize("cli", ["data", "sweep", "evaluate"])
def test_every_writer_refuses_an_owned_directory_before_working(cli, cross_net, tmp_path, capsys):
    out = tmp_path / "out"
    if cli == "data":
        from sumo_scendiff.data.__main__ import get_options, main
        args, held = ["-n", cross_net, "-o", str(out), "--scenes", "5"], f"{out}.partial"
    elif cli == "sweep":
        from sumo_scendiff.sweep.__main__ import get_options, main
        spec = tmp_path / "s.toml"
        spec.write_text(f'name = "t"\nnetworks = ["{cross_net}"]\nlocations = [{{center = [0.0, 0.0]}}]\n')
        args, held = ["--spec", str(spec), "--out", str(out)], str(out)
    else:
        from sumo_scendiff.evaluate.__main__ import get_options, main
        args, held = ["-n", cross_net, "--pictures", str(out), "--no-model"], str(out)
    p = _holder(held)
    try:
        with pytest.raises(SystemExit) as e:
            main(get_options(args))
    finally:
        p.kill()
        p.wait()
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert f"error: {held}: in use by process {p.pid}" in err
    assert os.listdir(held) == [LOCK]      # nothing written beside the holder's lock
