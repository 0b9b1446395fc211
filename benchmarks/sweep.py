"""Benchmark: the three targets of the sweep issue -- parallel speed-up, resume after SIGKILL, and
flat worker memory over a long sweep.

    python benchmarks/sweep.py speedup [--scenarios 40] [--workers 1 2] [--rollout 30]
    python benchmarks/sweep.py kill [--scenarios 40] [--kills 5] [--kill-at time|count] [--rollout 30]
    python benchmarks/sweep.py memory [--scenarios 500] [--rollout 5] [--interval 1]
    python benchmarks/sweep.py all -o runs/bench_sweep.md      # the three at their defaults
    python benchmarks/sweep.py speedup --scenarios 8 -o runs/bench_sweep_small.md   # a quick check

Every sweep runs the real CLI as a subprocess (``python -m sumo_scendiff.sweep --spec SPEC --out DIR
--workers N --no-pictures``, in a new session) on a spec written into the work directory (a temp
dir, removed at the end unless ``--keep``; or ``--workdir DIR``):

* **speedup** -- ``networks/city.net.xml``, 4 auto locations x a truck token set with 2 variants
  (final speed 0 / 8 m/s, as ``scenarios/truck_stopping.toml``) x p_mask 0.2 ... 1.0 (5 values), seed
  0 = 40 scenarios, 30-s rollouts; once per ``--workers`` value into a fresh directory, wall clock
  from the start of the process to its exit. Prints the times, the speed-up over the first value
  (target >= 1.8x), the bound that the task granularity (tasks of up to 8 scenarios) puts on it,
  and whether the index.jsonl files are identical (same seeds -> same scenes).
* **kill** -- the same sweep with ``--workers 2``: once uninterrupted (the reference), then started,
  SIGKILLed (the sweep's main process only: its workers must die with it) and started again with
  ``--resume``, ``--kills`` times (resumed runs are killed too), then left to finish. ``--kill-at
  time``: after a delay drawn uniformly between ``--min-delay`` and the reference's duration scaled
  to the scenarios still to run (start-up included), so every kill lands in a running sweep;
  ``--kill-at count``: when a random number of further scenarios has finished. The draws come from
  ``--seed`` only. After each kill: every process of the sweep's session (and any process whose
  command line names the output directory) must be gone within ``--orphan-wait`` s; each resumed
  run must report "K done before" with K = the scenario folders left by the kill. At the end:
  scenarios lost (planned, neither folder nor failure), duplicated (folders not in the plan, ids
  twice in the index), ``*.partial`` left anywhere, and whether index.jsonl equals the reference's.
* **memory** -- a long sweep (500 scenarios: 5 auto locations x 10 p_mask values x 10 seeds, no
  tokens, 5-s rollouts) with ``--workers 2``; the RSS of every worker process (the sweep's
  ``multiprocessing`` children; the main process too) is sampled every ``--interval`` s (psutil if
  installed, else /proc). Per process: RSS once the first task is done (the first sample with
  8 x workers scenarios finished), at the end, the peak, and the least-squares slope of RSS against
  scenarios finished over the second half of the sweep, in MiB per 100 scenarios (of the sweep);
  "flat" = |slope| < ``--flat`` (5 MiB / 100). ``--samples FILE`` writes the raw samples (CSV).

``--scenarios N`` other than the full product: the product is extended with more seeds if needed
and N scenarios are drawn from it with ``--seed`` (written as the spec's explicit list, plan order).
Everything except the timings is deterministic for a seed. Prints markdown tables with the command
(and writes them with ``-o``). Timing numbers are only meaningful on an otherwise idle machine: the
header shows the load average at the start.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
CITY = os.path.join(ROOT, "networks", "city.net.xml")
TRUCK = {"name": "truck", "agents": [{"x": 12.0, "y": -1.6, "heading": 0.0, "length": 10.5, "width": 2.5,
                                      "speed": 8.0}], "vary": {"final_speed": [0.0, 8.0]}}
MIB = 1024.0 * 1024.0
DONE_BEFORE = re.compile(r"(\d+) scenarios, (\d+) done before")
SCN = re.compile(r"^s\d{4,}$")

# --------------------------------------------------------------------------------------------------
# options


def _common(p: argparse.ArgumentParser, scenarios: int | None, rollout: float | None) -> None:
    if scenarios is not None:
        p.add_argument("--scenarios", type=int, default=scenarios, help=f"sweep size (default {scenarios})")
        p.add_argument("--rollout", type=float, default=rollout, help=f"rollout seconds (default {rollout:g})")
        p.add_argument("--steps", type=int, default=20, help="sampler steps (default 20, the sweep's)")
        p.add_argument("--pictures", action="store_true", help="let the sweep draw its pictures (timed too)")
    p.add_argument("-s", "--seed", type=int, default=0, help="subsample and kill draws (default 0)")
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="also write the tables here")
    p.add_argument("--workdir", default=None, help="specs and sweep outputs (default: a temp dir)")
    p.add_argument("--keep", action="store_true", help="keep the work directory")
    p.add_argument("--timeout", type=float, default=4 * 3600.0, help="per sweep process (s)")
    p.add_argument("--hash-seed", default=None, metavar="N",
                   help="diagnostic: PYTHONHASHSEED for the sweep processes (default: Python's random one)")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = p.add_subparsers(dest="what", required=True, metavar="speedup|kill|memory|all")
    sp = sub.add_parser("speedup", help="the same sweep with --workers 1 and 2")
    _common(sp, 40, 30.0)
    sp.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="values to compare (default 1 2)")
    sp.add_argument("--target", type=float, default=1.8, help="speed-up target (default 1.8)")
    kp = sub.add_parser("kill", help="SIGKILL + --resume, repeated; compared with an uninterrupted sweep")
    _common(kp, 40, 30.0)
    kp.add_argument("--workers", type=int, default=2)
    kp.add_argument("--kills", type=int, default=5)
    kp.add_argument("--kill-at", choices=("time", "count"), default="time")
    kp.add_argument("--min-delay", type=float, default=2.0, help="earliest kill after a start (s)")
    kp.add_argument("--orphan-wait", type=float, default=10.0, help="grace for the workers to die (s)")
    mp = sub.add_parser("memory", help="worker RSS over a long sweep")
    _common(mp, 500, 5.0)
    mp.add_argument("--workers", type=int, default=2)
    mp.add_argument("--interval", type=float, default=1.0, help="RSS sample period (s)")
    mp.add_argument("--flat", type=float, default=5.0, help="|slope| below this (MiB / 100 scenarios) is flat")
    mp.add_argument("--samples", default=None, metavar="FILE", help="write the raw samples (CSV)")
    ap = sub.add_parser("all", help="speedup, kill (its reference: speedup's --workers 2 run), memory; defaults")
    _common(ap, None, None)
    ap.add_argument("--quick", action="store_true", help="a self-check of this script, not a measurement: "
                    "8 scenarios and 2 kills, memory 40 scenarios with 1-s rollouts")
    o = p.parse_args(args)
    if getattr(o, "scenarios", 1) < 1:
        p.error("--scenarios must be >= 1")
    return o


# --------------------------------------------------------------------------------------------------
# specs


def write_spec(path: str, name: str, n: int, seed: int, locations: int, p_masks: list[float], seeds: int,
               token_sets: list[dict] | None, rollout: float, steps: int) -> str:
    """The cross product when it has exactly n scenarios; else (more seeds if needed) n of them drawn
    with ``seed``, written as the explicit list (plan order). ``locations`` stays in the spec, so the
    auto windows are the same whichever are drawn."""
    from sumo_scendiff.sweep.spec import load_spec
    data = {"name": name, "networks": [CITY], "locations": [{"auto": locations}], "p_mask": p_masks,
            "seeds": seeds, "steps": steps, "rollout": rollout}
    if token_sets:
        data["token_sets"] = token_sets
    for _ in range(2):   # the second time with enough seeds
        with open(path, "w") as f:
            json.dump(data, f, indent=1)
        full = load_spec(path).scenarios()
        data["seeds"] = max(seeds, math.ceil(n * seeds / len(full)))
    if len(full) != n:
        pick = sorted(random.Random(seed).sample(range(len(full)), n)) if n < len(full) else range(n)
        data["scenarios"] = [{"network": s.network, "location": s.location, "token_set": s.token_set,
                              "p_mask": s.p_mask, "seed": s.seed} for s in (full[k] for k in pick)]
        for key in ("p_mask", "seeds"):
            del data[key]
        with open(path, "w") as f:
            json.dump(data, f, indent=1)
    assert len(load_spec(path).scenarios()) == n
    return path


def truck_spec(o, workdir: str) -> str:
    return write_spec(os.path.join(workdir, f"truck{o.scenarios}.json"), "bench_truck", o.scenarios, o.seed,
                      locations=4, p_masks=[0.2, 0.4, 0.6, 0.8, 1.0], seeds=1, token_sets=[TRUCK],
                      rollout=o.rollout, steps=o.steps)


def long_spec(o, workdir: str) -> str:
    return write_spec(os.path.join(workdir, f"long{o.scenarios}.json"), "bench_long", o.scenarios, o.seed,
                      locations=5, p_masks=[round(0.1 * k, 1) for k in range(1, 11)], seeds=10,
                      token_sets=None, rollout=o.rollout, steps=o.steps)


def plan_ids(spec: str) -> list[str]:
    from sumo_scendiff.sweep.spec import load_spec
    return [s.id for s in load_spec(spec).scenarios()]


# --------------------------------------------------------------------------------------------------
# processes (psutil if installed, else /proc)

try:
    import psutil
except ImportError:
    psutil = None


def _stat(pid: int):
    """(state, ppid, starttime) or None if gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            data = f.read()
    except OSError:
        return None
    rest = data[data.rindex(")") + 2:].split()
    return rest[0], int(rest[1]), int(rest[19])


def cmdline(pid: int) -> str:
    try:
        if psutil is not None:
            return " ".join(psutil.Process(pid).cmdline())
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except Exception:
        return ""


def pids() -> list[int]:
    if psutil is not None:
        return psutil.pids()
    return [int(d) for d in os.listdir("/proc") if d.isdigit()]


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
    out = []
    for p in pids():
        st = _stat(p)
        if st is not None and st[1] == pid:
            out.append(p)
    return out


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
    me = {os.getpid(), os.getppid()}
    return [p for p in pids() if p not in me and text in cmdline(p) and alive(p)]


# --------------------------------------------------------------------------------------------------
# one sweep process


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


class Progress:
    """tqdm on a terminal, otherwise a line every 30 s."""

    def __init__(self, desc: str, total: int, initial: int = 0):
        self.desc, self.total, self.n, self.last = desc, total, initial, time.perf_counter()
        self.bar = None
        if sys.stderr.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=total, initial=initial, desc=desc, unit=" scn", leave=False)
        else:
            print(f"{desc}: {initial}/{total} scenarios", file=sys.stderr, flush=True)

    def update(self, n: int, extra: str = "") -> None:
        if n != self.n and self.bar is not None:
            self.bar.update(n - self.n)
        self.n = n
        if self.bar is None and time.perf_counter() - self.last >= 30.0:
            self.last = time.perf_counter()
            print(f"{self.desc}: {n}/{self.total} scenarios {extra}".rstrip(), file=sys.stderr, flush=True)

    def close(self, note: str = "") -> None:
        if self.bar is not None:
            self.bar.close()
        print(f"{self.desc}: {self.n}/{self.total} scenarios {note}".rstrip(), file=sys.stderr, flush=True)


class Sweep:
    """``python -m sumo_scendiff.sweep`` as a subprocess in its own session (so the session id finds
    every process it started, even after it is killed)."""

    hash_seed = None   # PYTHONHASHSEED for the sweep (main.py sets it from --hash-seed)

    def __init__(self, spec: str, out: str, workers: int, log: str, resume: bool = False,
                 pictures: bool = False):
        self.out, self.log = out, log
        self.cmd = [sys.executable, "-m", "sumo_scendiff.sweep", "--spec", spec, "--out", out,
                    "--workers", str(workers)] + (["--resume"] if resume else []) + \
                   ([] if pictures else ["--no-pictures"])
        self.proc = None

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

    def wait(self, period: float) -> bool:
        """Wait up to period; True when the process has exited (self.wall set)."""
        try:
            self.proc.wait(timeout=period)
        except subprocess.TimeoutExpired:
            return False
        self.wall = self.elapsed()
        self._log.close()
        return True

    def text(self) -> str:
        with open(self.log, errors="replace") as f:
            return f.read()

    def done_before(self) -> int | None:
        m = DONE_BEFORE.search(self.text())
        return int(m.group(2)) if m else None

    def kill_all(self) -> None:
        """Our own sweep's process group (after a timeout or an interruption of the benchmark)."""
        if self.proc is not None and self.proc.poll() is None:
            try:
                os.killpg(self.pid, signal.SIGKILL)
            except OSError:
                pass
            self.proc.wait()
            self.wall = self.elapsed()


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
    process still running). ``sample(elapsed, done)`` is called every ``period`` s."""
    sw.start()
    prog = Progress(desc, total, sum(count_done(sw.out)))
    sw.stopped = False
    try:
        while True:
            if sw.wait(period):
                break
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


# --------------------------------------------------------------------------------------------------
# indexes


def read_index(out: str) -> list[dict]:
    path = os.path.join(out, "index.jsonl")
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def _close(x, y) -> bool:
    if isinstance(x, float) and isinstance(y, float):
        return math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-12)
    return x == y


def compare(a: list[dict], b: list[dict]) -> str:
    """Exactly equal, or which rows and columns differ (and whether only in float rounding)."""
    if a == b:
        return "**yes**"
    if len(a) != len(b):
        return f"**no** ({len(a)} vs {len(b)} rows)"
    bad = [(x, y) for x, y in zip(a, b) if x != y]
    cols = sorted({k for x, y in bad for k in set(x) | set(y) if x.get(k) != y.get(k)})
    rounding = all(_close(x.get(k), y.get(k)) for x, y in bad for k in cols)
    return (f"**no** ({len(bad)} of {len(a)} rows differ; columns: {', '.join(cols)}"
            + ("; only in float rounding, rel. < 1e-9)" if rounding else ")"))


def partial_left(out: str) -> list[str]:
    left = []
    for d, dirs, files in os.walk(out):
        left += [os.path.relpath(os.path.join(d, n), out) for n in dirs + files if n.endswith(".partial")]
    return left


def status_counts(rows: list[dict]) -> str:
    c = {}
    for r in rows:
        c[r["status"]] = c.get(r["status"], 0) + 1
    return ", ".join(f"{k} {v}" for k, v in sorted(c.items())) or "no index"


def granularity_bound(spec: str, workers: int) -> tuple[float, int]:
    """The best speed-up the task split allows (longest-first on ``workers``), and the task count."""
    from sumo_scendiff.sweep.engines import tasks
    from sumo_scendiff.sweep.spec import load_spec
    sizes = sorted((len(t) for t in tasks(load_spec(spec).scenarios())), reverse=True)
    load = [0] * workers
    for s in sizes:
        load[load.index(min(load))] += s
    return sum(sizes) / max(load), len(sizes)


# --------------------------------------------------------------------------------------------------
# the three measurements


def header(o, command: str) -> list[str]:
    la = os.getloadavg()
    return [f"Command: `{command}`", "",
            f"{os.cpu_count()} CPUs, load average at the start {la[0]:.2f} / {la[1]:.2f} / {la[2]:.2f} "
            f"(1 / 5 / 15 min; timings mean something only on an idle machine)"
            + (f"; sweeps run with PYTHONHASHSEED={o.hash_seed}" if o.hash_seed is not None else ""), ""]


def sweep_cmd(spec: str, workers, extra: str = "", pictures: bool = False) -> str:
    return (f"python -m sumo_scendiff.sweep --spec {os.path.basename(spec)} --out DIR --workers {workers}"
            f"{'' if pictures else ' --no-pictures'}{extra}")


def speedup(o, workdir: str, command: str) -> tuple[str, dict]:
    spec = truck_spec(o, workdir)
    n = o.scenarios
    res = {}
    for w in o.workers:
        out = os.path.join(workdir, f"speedup_w{w}")
        shutil.rmtree(out, ignore_errors=True)
        tl = Timeline(n)
        sw = run_sweep(Sweep(spec, out, w, out + ".log", pictures=o.pictures), n, f"speedup --workers {w}",
                       o.timeout, sample=tl)
        res[w] = {"out": out, "wall": sw.wall, "first": tl.first or sw.wall, "last": tl.last or sw.wall,
                  "rows": read_index(out), "exit": sw.proc.returncode}
    base = o.workers[0]
    lines = header(o, command) + [
        f"`{sweep_cmd(spec, 'N', pictures=o.pictures)}` as a subprocess, fresh DIR each; {n} scenarios "
        f"(networks/city.net.xml, 4 auto locations x truck final_speed 0/8 x p_mask 0.2..1.0"
        f"{', drawn' if n != 40 else ''}), {o.steps} sampler steps, {o.rollout:g}-s rollouts; "
        f"wall clock from the start of the process to its exit", "",
        "| | " + " | ".join(f"`--workers {w}`" for w in o.workers) + " |",
        "|---|" + "---|" * len(o.workers)]

    def row(name, cells):
        lines.append(f"| {name} | " + " | ".join(cells) + " |")

    row("wall clock (s)", [f"{res[w]['wall']:.1f}" for w in o.workers])
    row("first / last scenario finished after (s)",
        [f"{res[w]['first']:.1f} / {res[w]['last']:.1f}" for w in o.workers])
    row("s / scenario (wall / scenarios)", [f"{res[w]['wall'] / n:.2f}" for w in o.workers])
    row("scenarios (index status)", [status_counts(res[w]["rows"]) for w in o.workers])
    row("exit code", [str(res[w]["exit"]) for w in o.workers])
    row(f"**speed-up** over `--workers {base}` (target ≥ {o.target:g}x)",
        [f"**{res[base]['wall'] / res[w]['wall']:.2f}x**" + ("" if w == base else
         " (met)" if res[base]["wall"] / res[w]["wall"] >= o.target else " (not met)") for w in o.workers])
    bounds = [granularity_bound(spec, w) for w in o.workers]
    row("bound from the task split (tasks of ≤ 8 scenarios)", [f"{b:.2f}x ({k} tasks)" for b, k in bounds])
    row(f"index.jsonl identical to `--workers {base}`'s", [compare(res[base]["rows"], res[w]["rows"])
                                                          if w != base else "–" for w in o.workers])
    return "\n".join(lines), res


def kill(o, workdir: str, command: str, reference: dict | None = None) -> str:
    spec = truck_spec(o, workdir)
    n, ids = o.scenarios, plan_ids(spec)
    if reference is None:
        out = os.path.join(workdir, f"kill_reference_w{o.workers}")
        shutil.rmtree(out, ignore_errors=True)
        tl = Timeline(n)
        sw = run_sweep(Sweep(spec, out, o.workers, out + ".log"), n, "kill: uninterrupted reference", o.timeout,
                       sample=tl)
        reference = {"out": out, "wall": sw.wall, "first": tl.first or sw.wall, "last": tl.last or sw.wall,
                     "rows": read_index(out)}
    t_ref, t_first, t_last = reference["wall"], reference["first"], reference["last"]
    rng = random.Random(o.seed)
    draws = [rng.random() for _ in range(o.kills)]   # all kill moments from the seed alone
    out = os.path.join(workdir, "kill_run")
    shutil.rmtree(out, ignore_errors=True)
    kills, runs = [], []
    expected_before = 0
    for k, u in enumerate(draws):
        folders, failed = count_done(out)
        remaining = n - folders
        if remaining <= 0:
            break
        if o.kill_at == "time":
            upper = t_first + (t_last - t_first) * remaining / n
            at = o.min_delay + u * max(upper - o.min_delay, 0.5)
            stop = lambda t, d, at=at: t >= at                                     # noqa: E731
            plan = f"after {at:.1f} s"
        else:
            target = folders + 1 + int(u * max(remaining - 1, 1))
            stop = lambda t, d, target=target: count_done(out)[0] >= target       # noqa: E731
            plan = f"at {target} folders"
        desc = f"kill {k + 1}/{o.kills} ({plan})"
        sw = run_sweep(Sweep(spec, out, o.workers, f"{out}.run{k + 1}.log", resume=k > 0), n, desc,
                       o.timeout, stop=stop, period=0.05)
        runs.append((k > 0, sw.done_before() if k > 0 else 0, expected_before))
        if not sw.stopped:   # it finished first (a kill drawn too late): no more kills
            kills.append({"plan": plan, "at": None, "note": f"finished first ({sw.wall:.1f} s)"})
            break
        members = [p for p in session_members(sw.pid) if p != sw.pid]   # workers, resource tracker
        at = sw.elapsed()
        os.kill(sw.pid, signal.SIGKILL)          # the main process only: its workers must die with it
        sw.proc.wait()
        sw._log.close()
        t_kill = time.perf_counter()
        gone_after = None
        while time.perf_counter() - t_kill < o.orphan_wait:
            if not session_members(sw.pid):
                gone_after = time.perf_counter() - t_kill
                break
            time.sleep(0.02)
        survivors = sorted(set(session_members(sw.pid)) | set(naming(out)))
        notes = [f"{p}: {cmdline(p)[:120]}" for p in survivors]
        for p in survivors:                      # ours (started by this sweep): do not let them write on
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass
        time.sleep(0.2)
        folders, failed = count_done(out)
        expected_before = folders
        kills.append({"plan": plan, "at": at, "resumed": k > 0, "members": len(members), "folders": folders,
                      "failed": failed, "partial": len([e for e in os.listdir(out) if e.endswith(".partial")]),
                      "gone_after": gone_after, "survivors": notes})
    final = None
    if not runs or kills and kills[-1]["at"] is not None:
        final = run_sweep(Sweep(spec, out, o.workers, f"{out}.final.log", resume=bool(kills)), n,
                          "kill: final --resume", o.timeout)
        runs.append((bool(kills), final.done_before(), expected_before))

    def before_text(b) -> str:   # the sweep prints "K done before" only when something is left to run
        return "– (nothing left to run)" if b is None else str(b)
    rows = read_index(out)
    row_ids = [r["id"] for r in rows]
    status = {r["id"]: r["status"] for r in rows}
    lost = [i for i in ids if status.get(i, "missing") == "missing"]
    folders = sorted(e for e in os.listdir(out) if SCN.match(e.split(".")[0]) and not e.endswith(".partial"))
    extra = sorted({e.split(".")[0] for e in folders} - set(ids))
    twice = sorted({i for i in row_ids if row_ids.count(i) > 1})
    left = partial_left(out)
    n_kills = sum(1 for x in kills if x["at"] is not None)
    orphans = sum(len(x.get("survivors", [])) for x in kills)
    wrong_before = [(b, e) for resumed, b, e in runs if resumed and (n if b is None else b) != e]
    exhausted = n_kills < o.kills and not (kills and kills[-1]["at"] is None)
    lines = header(o, command) + [
        f"`{sweep_cmd(spec, o.workers, ' [--resume]')}` as a subprocess in its own session; {n} scenarios "
        f"(as speedup), {o.rollout:g}-s rollouts. Reference: the same sweep uninterrupted, {t_ref:.1f} s "
        f"(first scenario after {t_first:.1f} s). Kill moments (`--kill-at {o.kill_at}`, seed {o.seed}): "
        + ("uniform between --min-delay and the time the reference's last scenario appeared, scaled "
           "to the scenarios left (start-up included)"
           if o.kill_at == "time" else "a uniform number of further finished scenarios") +
        "; SIGKILL to the sweep's main process only.", "",
        "| kill | run | planned | killed after (s) | scenario folders after the kill | other processes of the "
        "sweep before → left after " + f"{o.orphan_wait:g} s | all gone after (s) | next run: \"done before\" |",
        "|---|---|---|---|---|---|---|---|"]
    for k, x in enumerate(kills):
        nxt = runs[k + 1][1] if k + 1 < len(runs) else None
        if x["at"] is None:
            lines.append(f"| {k + 1} | {'resumed' if k else 'first'} | {x['plan']} | – ({x['note']}) | | | | |")
            continue
        lines.append(f"| {k + 1} | {'resumed' if x['resumed'] else 'first'} | {x['plan']} | {x['at']:.1f} | "
                     f"{x['folders']} (+{x['failed']} failed, {x['partial']} .partial) | {x['members']} → "
                     f"{len(x['survivors'])} | " + (f"{x['gone_after']:.2f}" if x["gone_after"] is not None
                                                     else "**not all**") +
                     f" | {before_text(nxt)}{'' if (n if nxt is None else nxt) == x['folders'] else ' **≠**'} |")
    for x in kills:
        for s in x.get("survivors", []):
            lines.append(f"\nsurvivor (killed by the benchmark): `{s}`")
    same = compare(reference["rows"], rows)
    ok_rest = not lost and not extra and not twice and not left and not orphans and not wrong_before \
        and (n_kills == o.kills or exhausted)
    verdict = "**FAIL**" if not ok_rest or same.startswith("**no**") and "rounding" not in same else \
        "**pass**" if rows == reference["rows"] else "**pass except float rounding in the index**"
    fin = "–" if final is None else (f"{'--resume' if kills else 'fresh'}, {before_text(final.done_before())} "
                                     f"done before, exit {final.proc.returncode}, {final.wall:.1f} s")
    lines += ["", "| | |", "|---|---|",
              f"| kills (SIGKILL while running) | {n_kills} of {o.kills}"
              f"{' (no scenario left to run after the last one)' if exhausted else ''} |",
              f"| final run | {fin} |",
              f"| index status (final / reference) | {status_counts(rows)} / {status_counts(reference['rows'])} |",
              f"| scenarios lost (planned, neither folder nor failure) | {len(lost)}{': ' + ' '.join(lost[:10]) if lost else ''} |",
              f"| duplicated: folders not in the plan / ids twice in the index | {len(extra)} / {len(twice)}"
              f"{': ' + ' '.join((extra + twice)[:10]) if extra or twice else ''} |",
              f"| `*.partial` left | {len(left)}{': ' + ' '.join(left[:10]) if left else ''} |",
              f"| orphan processes after the kills | {orphans} |",
              f"| \"done before\" ≠ folders left by the kill | {len(wrong_before)} |",
              f"| **index.jsonl equal to the uninterrupted one** | {same} |",
              f"| **all checks** | {verdict} |"]
    return "\n".join(lines)


def memory(o, workdir: str, command: str) -> str:
    import numpy as np
    spec = long_spec(o, workdir)
    n = o.scenarios
    out = os.path.join(workdir, "memory")
    shutil.rmtree(out, ignore_errors=True)
    samples = []      # (t, done, {pid: rss})
    roles = {}
    state = {"next": 0.0}
    sw = Sweep(spec, out, o.workers, out + ".log", pictures=o.pictures)

    def sample(t, done):
        if t < state["next"]:
            return
        state["next"] = t + o.interval
        procs = {sw.pid: "main"} if o.workers > 1 else {sw.pid: "main (the worker)"}
        for c in children(sw.pid):
            if roles.get(c, "other") == "other":   # "other": maybe forked but not yet exec'd
                cl = cmdline(c)
                roles[c] = "resource tracker" if "resource_tracker" in cl else "worker" \
                    if "multiprocessing" in cl or "spawn_main" in cl else "other"
            if roles[c] != "resource tracker":
                procs[c] = roles[c]
        mem = {p: r for p in procs if (r := rss(p)) is not None}
        samples.append((t, done, mem))

    run_sweep(sw, n, f"memory --workers {o.workers}", o.timeout, sample=sample, period=min(0.2, o.interval))
    rows = read_index(out)
    if o.samples:
        os.makedirs(os.path.dirname(os.path.abspath(o.samples)) or ".", exist_ok=True)
        with open(o.samples, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t_s", "done", "pid", "role", "rss_mib"])
            for t, d, mem in samples:
                for p, r in mem.items():
                    w.writerow([f"{t:.2f}", d, p, "main" if p == sw.pid else roles.get(p, "?"), f"{r / MIB:.2f}"])
    first_task = min(n, 8 * o.workers)
    table = []
    for pid in sorted({p for _, _, m in samples for p in m}, key=lambda p: (p != sw.pid, p)):
        pts = [(t, d, m[pid] / MIB) for t, d, m in samples if pid in m]
        role = ("main" if o.workers > 1 else "main (the worker)") if pid == sw.pid else roles.get(pid, "?")
        after = next((r for t, d, r in pts if d >= first_task), None)
        half = [(d, r) for t, d, r in pts if d >= n / 2]
        slope = None
        if len({d for d, _ in half}) >= 2:
            slope = 100.0 * float(np.polyfit([d for d, _ in half], [r for _, r in half], 1)[0])
        table.append((f"{role} (pid {pid})", len(pts), after, pts[-1][2], max(r for _, _, r in pts),
                      slope, pts[0][1], pts[-1][1]))
    tasks_half = n / 2 / 8 / o.workers
    lines = header(o, command) + [
        f"`{sweep_cmd(spec, o.workers, pictures=o.pictures)}` as a subprocess; {n} scenarios "
        f"(networks/city.net.xml, 5 auto locations x p_mask 0.1..1.0 x seeds{', drawn' if n != 500 else ''}; "
        f"no tokens), {o.steps} sampler steps, {o.rollout:g}-s rollouts; RSS sampled every {o.interval:g} s "
        f"({'psutil' if psutil else '/proc'}). Wall clock {sw.wall:.1f} s, index: {status_counts(rows)}.", "",
        f"| process | samples | RSS after the first task (MiB; ≥ {first_task} scenarios done) | RSS at the end "
        f"(MiB) | peak (MiB) | **slope, second half (MiB / 100 scenarios)** | flat (< {o.flat:g}) | "
        f"scenarios done: first → last sample |", "|---|---|---|---|---|---|---|---|"]
    for name, k, after, end, peak, slope, d0, d1 in table:
        lines.append(f"| {name} | {k} | {'–' if after is None else f'{after:.0f}'} | {end:.0f} | {peak:.0f} | "
                     f"**{'–' if slope is None else f'{slope:+.1f}'}** | "
                     f"{'–' if slope is None else 'yes' if abs(slope) < o.flat else '**no**'} | {d0} → {d1} |")
    if tasks_half < 4:
        lines += ["", f"(The second half is only ~{tasks_half:.1f} tasks per worker: RSS swings within a task "
                  f"(the batched model call) dominate the slope; use ≥ {64 * o.workers} scenarios.)"]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------------


def main(o) -> int:
    import tempfile
    command = ("python benchmarks/sweep.py " + " ".join(sys.argv[1:])).strip() \
        if sys.argv[0].endswith("sweep.py") else f"benchmarks/sweep.py {o.what} (in-process)"
    if o.workdir:
        os.makedirs(o.workdir, exist_ok=True)
        workdir = os.path.abspath(o.workdir)
    else:
        workdir = tempfile.mkdtemp(prefix="bench-sweep-")
    print(f"work directory {workdir}", file=sys.stderr)
    Sweep.hash_seed = o.hash_seed
    t0 = time.perf_counter()
    parts = []
    try:
        if o.what == "all":
            common = ["-s", str(o.seed), "--timeout", str(o.timeout)] + \
                (["--hash-seed", o.hash_seed] if o.hash_seed is not None else [])
            small = ["--scenarios", "8"] if o.quick else []
            so = get_options(["speedup"] + common + small)
            text, res = speedup(so, workdir, command)
            parts.append(("speedup", text))
            ko = get_options(["kill"] + common + small + (["--kills", "2"] if o.quick else []))
            ref = res.get(ko.workers)
            parts.append(("kill", kill(ko, workdir, command, ref)))
            mo = get_options(["memory"] + common + (["--scenarios", "40", "--rollout", "1"] if o.quick else []))
            parts.append(("memory", memory(mo, workdir, command)))
        elif o.what == "speedup":
            parts.append(("speedup", speedup(o, workdir, command)[0]))
        elif o.what == "kill":
            parts.append(("kill", kill(o, workdir, command)))
        else:
            parts.append(("memory", memory(o, workdir, command)))
    finally:
        if not o.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    text = "\n\n".join(f"## {name}\n\n{body}" for name, body in parts) + \
        f"\n\nTotal wall time {time.perf_counter() - t0:.0f} s.\n"
    print(text)
    if o.output:
        os.makedirs(os.path.dirname(os.path.abspath(o.output)), exist_ok=True)
        with open(o.output, "w") as f:
            f.write("# sweep benchmark\n\n" + text)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
