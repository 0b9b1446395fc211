"""The three measurements of benchmarks/sweep.py (see its docstring): ``speedup``, ``kill`` and ``memory``,
each running the sweep CLI and returning its report (markdown, header included).
"""
from __future__ import annotations

import csv
import os
import random
import shutil

from sweep_data import (
    compare,
    granularity_bound,
    long_spec,
    partial_left,
    plan_ids,
    read_index,
    status_counts,
    truck_spec,
)
from sweep_procs import (
    BACKEND,
    SCN,
    Sweep,
    Timeline,
    children,
    cmdline,
    count_done,
    kill_main,
    rss,
    run_sweep,
)

MIB = 1024.0 * 1024.0


def header(o, command: str) -> list[str]:
    la = os.getloadavg()
    return [f"Command: `{command}`", "",
            f"{os.cpu_count()} CPUs, load average at the start {la[0]:.2f} / {la[1]:.2f} / {la[2]:.2f} "
            f"(1 / 5 / 15 min; timings mean something only on an idle machine)"
            + (f"; sweeps run with PYTHONHASHSEED={o.hash_seed}" if o.hash_seed is not None else ""), ""]


def sweep_cmd(spec: str, workers, extra: str = "", pictures: bool = False) -> str:
    return (f"python -m sumo_scendiff.sweep --spec {os.path.basename(spec)} --out DIR --workers {workers}"
            f"{'' if pictures else ' --no-pictures'}{extra}")


def timed_run(o, spec: str, out: str, workers: int, desc: str, pictures: bool = False) -> dict:
    """One uninterrupted sweep into a fresh ``out``: wall clock, when its first and last scenario
    appeared, its index rows and exit code."""
    shutil.rmtree(out, ignore_errors=True)
    tl = Timeline(o.scenarios)
    sw = run_sweep(Sweep(spec, out, workers, out + ".log", pictures=pictures, hash_seed=o.hash_seed),
                   o.scenarios, desc, o.timeout, sample=tl)
    return {"wall": sw.wall, "first": tl.first or sw.wall, "last": tl.last or sw.wall,
            "rows": read_index(out), "exit": sw.proc.returncode}


# --------------------------------------------------------------------------------------------------
# speedup


def speedup(o, workdir: str, command: str) -> tuple[str, dict]:
    """The report, and the runs by worker count (kill takes its reference from them)."""
    spec = truck_spec(o, workdir)
    n = o.scenarios
    res = {w: timed_run(o, spec, os.path.join(workdir, f"speedup_w{w}"), w, f"speedup --workers {w}",
                        pictures=o.pictures) for w in o.workers}
    base = o.workers[0]
    ratio = {w: res[base]["wall"] / res[w]["wall"] for w in o.workers}
    lines = header(o, command) + [
        f"`{sweep_cmd(spec, 'N', pictures=o.pictures)}` as a subprocess, fresh DIR each; {n} scenarios "
        f"(networks/city.net.xml, 4 auto locations x truck final_speed 0/8 x p_mask 0.2..1.0"
        f"{', drawn' if n != 40 else ''}), {o.steps} sampler steps, {o.rollout:g}-s rollouts; "
        f"wall clock from the start of the process to its exit", "",
        "| | " + " | ".join(f"`--workers {w}`" for w in o.workers) + " |",
        "|---|" + "---|" * len(o.workers)]

    def row(name, cell):
        lines.append(f"| {name} | " + " | ".join(cell(w) for w in o.workers) + " |")

    row("wall clock (s)", lambda w: f"{res[w]['wall']:.1f}")
    row("first / last scenario finished after (s)", lambda w: f"{res[w]['first']:.1f} / {res[w]['last']:.1f}")
    row("s / scenario (wall / scenarios)", lambda w: f"{res[w]['wall'] / n:.2f}")
    row("scenarios (index status)", lambda w: status_counts(res[w]["rows"]))
    row("exit code", lambda w: str(res[w]["exit"]))
    row(f"**speed-up** over `--workers {base}` (target ≥ {o.target:g}x)",
        lambda w: f"**{ratio[w]:.2f}x**" + ("" if w == base else " (met)" if ratio[w] >= o.target else " (not met)"))
    bounds = {w: granularity_bound(spec, w) for w in o.workers}
    row("bound from the task split (tasks of ≤ 8 scenarios)", lambda w: "{:.2f}x ({} tasks)".format(*bounds[w]))
    row(f"index.jsonl identical to `--workers {base}`'s",
        lambda w: "–" if w == base else compare(res[base]["rows"], res[w]["rows"]))
    return "\n".join(lines), res


# --------------------------------------------------------------------------------------------------
# kill


def kill(o, workdir: str, command: str, reference: dict | None = None) -> str:
    """``reference``: an uninterrupted run of the same sweep (from speedup), else one is run first."""
    spec = truck_spec(o, workdir)
    if reference is None:
        reference = timed_run(o, spec, os.path.join(workdir, f"kill_reference_w{o.workers}"), o.workers,
                              "kill: uninterrupted reference")
    out = os.path.join(workdir, "kill_run")
    kills, runs, final = _kill_runs(o, spec, out, reference)
    return _kill_report(o, command, spec, out, reference, kills, runs, final)


def _kill_moment(o, u: float, out: str, folders: int, ref: dict):
    """(description, stop(elapsed, done)) for the uniform draw u, ``folders`` scenarios done before."""
    n, remaining = o.scenarios, o.scenarios - folders
    if o.kill_at == "time":
        upper = ref["first"] + (ref["last"] - ref["first"]) * remaining / n
        at = o.min_delay + u * max(upper - o.min_delay, 0.5)
        return f"after {at:.1f} s", lambda t, d: t >= at
    target = folders + 1 + int(u * max(remaining - 1, 1))
    return f"at {target} folders", lambda t, d: count_done(out)[0] >= target


def _kill_runs(o, spec: str, out: str, reference: dict):
    """Start, SIGKILL, start again with --resume, ``o.kills`` times, then let it finish. Returns the
    kills, the runs as (resumed, its "done before", the folders the kill before it left) and the
    final run (None when the last run finished before its kill)."""
    n = o.scenarios
    rng = random.Random(o.seed)
    draws = [rng.random() for _ in range(o.kills)]   # all kill moments from the seed alone
    shutil.rmtree(out, ignore_errors=True)
    kills, runs = [], []
    expected_before = 0
    for k, u in enumerate(draws):
        folders = count_done(out)[0]
        if folders >= n:
            break
        plan, stop = _kill_moment(o, u, out, folders, reference)
        sw = run_sweep(Sweep(spec, out, o.workers, f"{out}.run{k + 1}.log", resume=k > 0, hash_seed=o.hash_seed),
                       n, f"kill {k + 1}/{o.kills} ({plan})", o.timeout, stop=stop, period=0.05)
        runs.append((k > 0, sw.done_before() if k > 0 else 0, expected_before))
        if not sw.stopped:   # it finished first (a kill drawn too late): no more kills
            kills.append({"plan": plan, "at": None, "note": f"finished first ({sw.wall:.1f} s)"})
            break
        x = kill_main(sw, o.orphan_wait)
        folders, failed = count_done(out)
        expected_before = folders
        kills.append({"plan": plan, "resumed": k > 0, "folders": folders, "failed": failed,
                      "partial": len([e for e in os.listdir(out) if e.endswith(".partial")]), **x})
    final = None
    if not kills or kills[-1]["at"] is not None:
        final = run_sweep(Sweep(spec, out, o.workers, f"{out}.final.log", resume=bool(kills), hash_seed=o.hash_seed),
                          n, "kill: final --resume", o.timeout)
        runs.append((bool(kills), final.done_before(), expected_before))
    return kills, runs, final


def _before_text(b) -> str:   # the sweep prints "K done before" only when something is left to run
    return "– (nothing left to run)" if b is None else str(b)


def _listed(items: list[str]) -> str:
    return ": " + " ".join(items[:10]) if items else ""


def _kill_report(o, command, spec, out, reference, kills, runs, final) -> str:
    n, ids = o.scenarios, plan_ids(spec)
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
        f"(as speedup), {o.rollout:g}-s rollouts. Reference: the same sweep uninterrupted, {reference['wall']:.1f} s "
        f"(first scenario after {reference['first']:.1f} s). Kill moments (`--kill-at {o.kill_at}`, seed {o.seed}): "
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
                     f" | {_before_text(nxt)}{'' if (n if nxt is None else nxt) == x['folders'] else ' **≠**'} |")
    for x in kills:
        for s in x.get("survivors", []):
            lines.append(f"\nsurvivor (killed by the benchmark): `{s}`")
    same = compare(reference["rows"], rows)
    ok_rest = not lost and not extra and not twice and not left and not orphans and not wrong_before \
        and (n_kills == o.kills or exhausted)
    verdict = "**FAIL**" if not ok_rest or same.startswith("**no**") and "rounding" not in same else \
        "**pass**" if same == "**yes**" else "**pass except float rounding in the index**"
    fin = "–" if final is None else (f"{'--resume' if kills else 'fresh'}, {_before_text(final.done_before())} "
                                     f"done before, exit {final.proc.returncode}, {final.wall:.1f} s")
    lines += ["", "| | |", "|---|---|",
              f"| kills (SIGKILL while running) | {n_kills} of {o.kills}"
              f"{' (no scenario left to run after the last one)' if exhausted else ''} |",
              f"| final run | {fin} |",
              f"| index status (final / reference) | {status_counts(rows)} / {status_counts(reference['rows'])} |",
              f"| scenarios lost (planned, neither folder nor failure) | {len(lost)}{_listed(lost)} |",
              f"| duplicated: folders not in the plan / ids twice in the index | {len(extra)} / {len(twice)}"
              f"{_listed(extra + twice)} |",
              f"| `*.partial` left | {len(left)}{_listed(left)} |",
              f"| orphan processes after the kills | {orphans} |",
              f"| \"done before\" ≠ folders left by the kill | {len(wrong_before)} |",
              f"| **index.jsonl equal to the uninterrupted one** | {same} |",
              f"| **all checks** | {verdict} |"]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------------
# memory


def memory(o, workdir: str, command: str) -> str:
    import numpy as np
    spec = long_spec(o, workdir)
    n = o.scenarios
    out = os.path.join(workdir, "memory")
    shutil.rmtree(out, ignore_errors=True)
    samples = []      # (t, done, {pid: rss})
    roles = {}        # child pid -> "worker" | "resource tracker" | "other"
    state = {"next": 0.0}
    sw = Sweep(spec, out, o.workers, out + ".log", pictures=o.pictures, hash_seed=o.hash_seed)

    def sample(t, done):
        if t < state["next"]:
            return
        state["next"] = t + o.interval
        procs = [sw.pid]
        for c in children(sw.pid):
            if roles.get(c, "other") == "other":   # "other": maybe forked but not yet exec'd
                cl = cmdline(c)
                roles[c] = "resource tracker" if "resource_tracker" in cl else "worker" \
                    if "multiprocessing" in cl or "spawn_main" in cl else "other"
            if roles[c] != "resource tracker":
                procs.append(c)
        samples.append((t, done, {p: r for p in procs if (r := rss(p))}))   # 0: exited (zombie)

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
    main_role = "main" if o.workers > 1 else "main (the worker)"
    lines = header(o, command) + [
        f"`{sweep_cmd(spec, o.workers, pictures=o.pictures)}` as a subprocess; {n} scenarios "
        f"(networks/city.net.xml, 5 auto locations x p_mask 0.1..1.0 x seeds{', drawn' if n != 500 else ''}; "
        f"no tokens), {o.steps} sampler steps, {o.rollout:g}-s rollouts; RSS sampled every {o.interval:g} s "
        f"({BACKEND}). Wall clock {sw.wall:.1f} s, index: {status_counts(rows)}.", "",
        f"| process | samples | RSS after the first task (MiB; ≥ {first_task} scenarios done) | RSS at the end "
        f"(MiB) | peak (MiB) | **slope, second half (MiB / 100 scenarios)** | flat (< {o.flat:g}) | "
        f"scenarios done: first → last sample |", "|---|---|---|---|---|---|---|---|"]
    for pid in sorted({p for _, _, m in samples for p in m}, key=lambda p: (p != sw.pid, p)):
        pts = [(d, m[pid] / MIB) for _, d, m in samples if pid in m]
        role = main_role if pid == sw.pid else roles.get(pid, "?")
        after = next((r for d, r in pts if d >= first_task), None)
        half = [(d, r) for d, r in pts if d >= n / 2]
        slope = None
        if len({d for d, _ in half}) >= 2:
            slope = 100.0 * float(np.polyfit([d for d, _ in half], [r for _, r in half], 1)[0])
        lines.append(f"| {role} (pid {pid}) | {len(pts)} | {'–' if after is None else f'{after:.0f}'} | "
                     f"{pts[-1][1]:.0f} | {max(r for _, r in pts):.0f} | "
                     f"**{'–' if slope is None else f'{slope:+.1f}'}** | "
                     f"{'–' if slope is None else 'yes' if abs(slope) < o.flat else '**no**'} | "
                     f"{pts[0][0]} → {pts[-1][0]} |")
    tasks_half = n / 2 / 8 / o.workers
    if tasks_half < 4:
        lines += ["", f"(The second half is only ~{tasks_half:.1f} tasks per worker: RSS swings within a task "
                  f"(the batched model call) dominate the slope; use ≥ {64 * o.workers} scenarios.)"]
    return "\n".join(lines)
