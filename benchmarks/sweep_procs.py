"""Processes for benchmarks/sweep.py: inspection (psutil if installed, else /proc), one sweep CLI run as
a watched subprocess in its own session (``Sweep``, ``run_sweep``), and the SIGKILL of its main process
with the check that the rest of its session dies too (``kill_main``).
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

try:
    import psutil
except ImportError:
    psutil = None

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
BACKEND = "psutil" if psutil is not None else "/proc"
DONE_BEFORE = re.compile(r"(\d+) scenarios, (\d+) done before")
SCN = re.compile(r"^s\d{4,}$")

# --------------------------------------------------------------------------------------------------
# inspection


def _stat(pid: int):
    """(state, ppid) or None if gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            data = f.read()
    except OSError:
        return None
    rest = data[data.rindex(")") + 2:].split()
    return rest[0], int(rest[1])


def pids() -> list[int]:
    if psutil is not None:
        return psutil.pids()
    return [int(d) for d in os.listdir("/proc") if d.isdigit()]


def cmdline(pid: int) -> str:
    try:
        if psutil is not None:
            return " ".join(psutil.Process(pid).cmdline())
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except Exception:
        return ""


def alive(pid: int) -> bool:
    """Running (not gone, not a zombie)."""
    if psutil is not None:
        try:
            return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
        except psutil.Error:
            return False
    st = _stat(pid)
    return st is not None and st[0] not in ("Z", "X")


def children(pid: int) -> list[int]:
    if psutil is not None:
        try:
            return [c.pid for c in psutil.Process(pid).children()]
        except psutil.Error:
            return []
    return [p for p in pids() if (st := _stat(p)) is not None and st[1] == pid]


def rss(pid: int) -> int | None:
    try:
        if psutil is not None:
            return psutil.Process(pid).memory_info().rss
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except Exception:
        return None


def session_members(sid: int) -> list[int]:
    out = []
    for p in pids():
        try:
            if os.getsid(p) == sid and alive(p):
                out.append(p)
        except OSError:
            pass
    return out


def naming(text: str) -> list[int]:
    """Live processes (not this one or its parent) whose command line contains text."""
    me = {os.getpid(), os.getppid()}
    return [p for p in pids() if p not in me and text in cmdline(p) and alive(p)]


def count_done(out: str) -> tuple[int, int]:
    """(scenario folders, failure records) in out."""
    folders = failed = 0
    try:
        with os.scandir(out) as it:
            for e in it:
                if SCN.match(e.name) and e.is_dir():
                    folders += 1
                elif e.name.endswith(".failed.json"):
                    failed += 1
    except OSError:
        pass
    return folders, failed


# --------------------------------------------------------------------------------------------------
# one sweep process


class Progress:
    """tqdm on a terminal, otherwise a line every 30 s."""

    def __init__(self, desc: str, total: int, initial: int = 0):
        self.desc, self.total, self.n, self.last = desc, total, initial, time.perf_counter()
        self.bar = None
        if sys.stderr.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=total, initial=initial, desc=desc, unit=" scn", leave=False)
        else:
            self._print(initial)

    def _print(self, n: int, extra: str = "") -> None:
        print(f"{self.desc}: {n}/{self.total} scenarios {extra}".rstrip(), file=sys.stderr, flush=True)

    def update(self, n: int, extra: str = "") -> None:
        if n != self.n and self.bar is not None:
            self.bar.update(n - self.n)
        self.n = n
        if self.bar is None and time.perf_counter() - self.last >= 30.0:
            self.last = time.perf_counter()
            self._print(n, extra)

    def close(self, note: str = "") -> None:
        if self.bar is not None:
            self.bar.close()
        self._print(self.n, note)


class Sweep:
    """``python -m sumo_scendiff.sweep`` as a subprocess in its own session (so the session id finds
    every process it started, even after it is killed); output to the file ``log``."""

    def __init__(self, spec: str, out: str, workers: int, log: str, resume: bool = False,
                 pictures: bool = False, hash_seed: str | None = None):
        self.out, self.log, self.hash_seed = out, log, hash_seed
        self.cmd = [sys.executable, "-m", "sumo_scendiff.sweep", "--spec", spec, "--out", out,
                    "--workers", str(workers)] + (["--resume"] if resume else []) + \
                   ([] if pictures else ["--no-pictures"])
        self.proc, self.wall, self.stopped = None, None, False

    def start(self) -> "Sweep":
        self._log = open(self.log, "w")
        self.t0 = time.perf_counter()
        env = None if self.hash_seed is None else {**os.environ, "PYTHONHASHSEED": str(self.hash_seed)}
        self.proc = subprocess.Popen(self.cmd, cwd=ROOT, stdin=subprocess.DEVNULL, stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True, env=env)
        self.pid = self.proc.pid
        return self

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def _reap(self) -> None:
        self.proc.wait()
        self.wall = self.elapsed()
        self._log.close()

    def wait(self, period: float) -> bool:
        """Wait up to period; True when the process has exited (self.wall set)."""
        try:
            self.proc.wait(timeout=period)
        except subprocess.TimeoutExpired:
            return False
        self._reap()
        return True

    def text(self) -> str:
        with open(self.log, errors="replace") as f:
            return f.read()

    def done_before(self) -> int | None:
        """K of the sweep's "K done before" (it prints it only when something is left to run)."""
        m = DONE_BEFORE.search(self.text())
        return int(m.group(2)) if m else None

    def kill_all(self) -> None:
        """Our own sweep's process group (after a timeout or an interruption of the benchmark)."""
        if self.proc is not None and self.proc.poll() is None:
            try:
                os.killpg(self.pid, signal.SIGKILL)
            except OSError:
                pass
            self._reap()


class Timeline:
    """When the first and the last scenario of a sweep appeared (a ``sample`` callback)."""

    def __init__(self, total: int):
        self.total, self.first, self.last = total, None, None

    def __call__(self, t: float, done: int) -> None:
        if done and self.first is None:
            self.first = t
        if done >= self.total and self.last is None:
            self.last = t


def run_sweep(sw: Sweep, total: int, desc: str, timeout: float, stop=None, sample=None,
              period: float = 0.2) -> Sweep:
    """Start and watch a sweep until it exits (or ``stop(elapsed, done)`` is true: returns with the
    process still running, ``sw.stopped``). ``sample(elapsed, done)`` is called every ``period`` s."""
    sw.start()
    prog = Progress(desc, total, sum(count_done(sw.out)))
    try:
        while not sw.wait(period):
            done = sum(count_done(sw.out))
            prog.update(done, f"{sw.elapsed():.0f} s")
            if sample is not None:
                sample(sw.elapsed(), done)
            if stop is not None and stop(sw.elapsed(), done):
                sw.stopped = True
                break
            if sw.elapsed() > timeout:
                sw.kill_all()
                raise RuntimeError(f"{desc}: no exit after {timeout:.0f} s (log: {sw.log})")
    except BaseException:
        if not sw.stopped:
            sw.kill_all()
        raise
    finally:
        prog.update(sum(count_done(sw.out)))
        prog.close("(running, to be killed)" if sw.stopped else
                   f"in {sw.wall:.1f} s, exit {sw.proc.returncode}" if sw.proc.poll() is not None else "")
    if not sw.stopped and sw.proc.returncode not in (0, 1):
        raise RuntimeError(f"{desc}: exit {sw.proc.returncode}: {sw.text().strip()[-2000:]}")
    return sw


def kill_main(sw: Sweep, orphan_wait: float) -> dict:
    """SIGKILL a stopped sweep's main process only (its workers must die with it), then wait up to
    ``orphan_wait`` s for the rest of its session to go. Whatever is left of the session, or names
    the output directory, is reported and killed (it must not write on)."""
    members = [p for p in session_members(sw.pid) if p != sw.pid]   # workers, resource tracker
    at = sw.elapsed()
    os.kill(sw.pid, signal.SIGKILL)
    sw.proc.wait()
    sw._log.close()
    t_kill = time.perf_counter()
    gone_after = None
    while time.perf_counter() - t_kill < orphan_wait:
        if not session_members(sw.pid):
            gone_after = time.perf_counter() - t_kill
            break
        time.sleep(0.02)
    survivors = sorted(set(session_members(sw.pid)) | set(naming(sw.out)))
    notes = [f"{p}: {cmdline(p)[:120]}" for p in survivors]
    for p in survivors:
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
    time.sleep(0.2)
    return {"at": at, "members": len(members), "gone_after": gone_after, "survivors": notes}
