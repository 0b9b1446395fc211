"""Record a training data set: networks and a scene count in, ``DIR/manifest.json`` and
``DIR/shard-*.npz`` out (what ``python -m sumo_scendiff.data`` runs).

    manifest = record_dataset(["networks/grid3.net.xml"], "data/train", scenes=20000, seed=0, workers=2)

Work happens in ``DIR.partial``, claimed by this process (:func:`sumo_scendiff.core.outputs.claim`)
from the first check to its rename to ``DIR``; ``DIR.partial/plan.json`` holds the options, so that
``resume=True`` continues an interrupted run only with the options it was started with, and
recomputes only the episodes not yet written. The same seed gives the same shards.
"""
from __future__ import annotations

import json
import os
import signal
from contextlib import closing
from dataclasses import replace

from ..core.outputs import claim
from ..core.procs import die_with_parent
from ..map.network import Network, NetworkError
from .demand import DemandError, check_routes
from .record import DENSITY, PEAK_DENSITY, plan_episodes, record_shard_task, spec_entry
from .shards import DataError, Shard, net_entry, write_manifest


class RecordingError(ValueError):
    """Input that cannot be recorded, or an episode that failed (one line, naming the file)."""


class RecordingInterrupted(KeyboardInterrupt):
    """A recording stopped by Ctrl-C or SIGTERM; its finished episodes are kept in ``partial``
    (``str()``: how many, where, and that ``resume`` continues)."""

    def __init__(self, partial: str, kept: int, episodes: int):
        super().__init__(f"{kept} of {episodes} episodes are kept in {partial}; --resume continues")
        self.partial, self.kept, self.episodes = partial, kept, episodes


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # SIGTERM ends a recording as Ctrl-C does: finished episodes are kept


def _record_all(tasks: list[tuple], workers: int):
    """Record the episodes ``tasks`` (``record_shard``'s arguments), yielding each one's manifest
    entry as it finishes; with several workers, in spawn processes that die with this one."""
    if workers <= 1:
        yield from map(record_shard_task, tasks)
        return
    import multiprocessing as mp
    pool = mp.get_context("spawn").Pool(workers, initializer=die_with_parent, initargs=(os.getpid(),))
    try:
        yield from pool.imap_unordered(record_shard_task, tasks)
        pool.close()
    finally:
        pool.terminate()  # after an error or an interrupt: episodes in progress are dropped
        pool.join()


def record_dataset(nets: list[str], out: str, scenes: int, seed: int, routes: list[str | None] | None = None,
                   per_episode: int = 300, density: tuple[float, float] = DENSITY, disc: bool = True,
                   workers: int = 1, resume: bool = False, progress: bool | None = None,
                   default_sizes: float = 0.0, peak_share: float = 0.0,
                   peak_density: tuple[float, float] = PEAK_DENSITY) -> dict:
    """Record ``scenes`` scenes from the networks ``nets`` into the directory ``out``; returns its
    manifest.

    ``routes``: each network's own demand file (or None: random trips of a density drawn
    log-uniformly from ``density``, veh/h/km of lane, per episode); ``per_episode``: scenes per
    SUMO run; ``disc``: record the circle through each window's corners (False: only the square);
    ``default_sizes``: the share of the random trips' fleet in SUMO's default vTypes of its classes;
    ``peak_share``: the share of random-demand episodes whose density comes from ``peak_density``;
    ``workers``: parallel SUMO processes; ``resume``: continue the interrupted run in
    ``out.partial``; ``progress``: a progress bar on stderr (None: when it is a terminal).

    Raises :class:`RecordingError` for input that cannot be recorded (nothing is left behind
    unless episodes were finished), :class:`~sumo_scendiff.core.outputs.OutputError` if
    ``out.partial`` is another live process's, and :class:`RecordingInterrupted` (a
    KeyboardInterrupt) on Ctrl-C or SIGTERM, after keeping the finished episodes."""
    if scenes <= 0:
        raise RecordingError(f"scenes must be positive, not {scenes}")
    for name, (lo, hi) in (("density", density), ("peak density", peak_density)):
        if not 0 < lo <= hi:
            raise RecordingError(f"{name} {lo:g} {hi:g}: need 0 < LO <= HI")
    for name, share in (("default sizes", default_sizes), ("peak share", peak_share)):
        if not 0 <= share <= 1:
            raise RecordingError(f"{name} {share:g}: need a share in [0, 1]")
    if routes and len(routes) != len(nets):
        raise RecordingError(f"give routes once per net ({len(nets)} nets, {len(routes)} route files)")
    path = os.path.abspath(out)
    # one recording at a time owns DIR.partial, from the first check to the rename to DIR
    with claim(path + ".partial") as owner:
        options = {"density": tuple(density), "default_sizes": default_sizes, "peak_share": peak_share,
                   "peak_density": tuple(peak_density)}
        return _record(owner, nets, out, path, scenes, seed, routes, per_episode, options, disc,
                       workers, resume, progress)


def _plan_config(options: dict) -> dict:
    """The demand options of ``plan.json``: each only when it differs from its default (plans of
    runs started before an option stay resumable)."""
    config = {}
    if options["density"] != DENSITY:
        config["density"] = list(options["density"])
    if options["default_sizes"]:
        config["default_sizes"] = options["default_sizes"]
    if options["peak_share"]:
        config["peak"] = [options["peak_share"], *options["peak_density"]]
    return config


def _record(owner, net_paths, given, out, scenes, seed, routes, per_episode, options, disc, workers,
            resume, progress) -> dict:
    from tqdm import tqdm
    partial = owner.directory
    if os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)):
        raise RecordingError(f"{given}: exists and is not empty (choose another --out)")
    if not owner.created and not resume:
        raise RecordingError(f"{partial}: an interrupted run is there; continue it with --resume or remove it")
    try:
        nets = [Network.load(p) for p in net_paths]
        routes: list[str | None] = list(routes or []) or [None] * len(nets)
        begins = [0.0 if r is None else check_routes(r, {ln.edge for ln in n.lanes})
                  for n, r in zip(nets, routes)]
    except (NetworkError, DemandError) as e:
        raise RecordingError(str(e)) from e
    names = [n.name for n in nets]
    if len(set(names)) != len(names):
        raise RecordingError(f"two networks share the name {names}: rename one")

    plan = plan_episodes(nets, [None if r is None else os.path.abspath(r) for r in routes], begins,
                         scenes, seed, per_episode, disc=disc, **options)
    config = {"nets": [os.path.abspath(p) for p in net_paths], "routes": routes, "scenes": scenes,
              "seed": seed, "scenes_per_episode": per_episode, **_plan_config(options)}
    if disc:
        config["disc"] = True
    plan_file = os.path.join(partial, "plan.json")
    if os.path.exists(plan_file):
        with open(plan_file) as f:
            if json.load(f) != config:
                raise RecordingError(f"{partial}: was started with other options; "
                                     f"remove it or repeat the original command")
    else:
        with open(plan_file, "w") as f:
            json.dump(config, f, indent=1)

    entries: dict[str, dict] = {}
    todo = []
    for k, name, spec in plan:
        path = os.path.join(partial, name)
        if os.path.exists(path):
            sh = Shard.load(path)
            entries[name] = {"file": name, "scenes": len(sh), "agents": int(sh.offsets[-1]), "net": k}
        else:
            todo.append((k, name, spec))
    for name in os.listdir(partial):  # an episode cut off while writing (the write is atomic)
        if name.endswith(".tmp.npz"):
            os.remove(os.path.join(partial, name))
    bar = tqdm(total=sum(s.scenes for _, _, s in plan), unit="scene", desc="recording",
               initial=sum(e["scenes"] for e in entries.values()),
               disable=None if progress is None else not progress)
    on_sigterm = signal.signal(signal.SIGTERM, _interrupt)  # put back below: callers go on
    try:
        tasks = [(nets[k].path, spec, k, os.path.join(partial, name)) for k, name, spec in todo]
        with closing(_record_all(tasks, workers)) as finished:
            for entry in finished:
                entries[entry["file"]] = entry
                bar.update(entry["scenes"])
    except (DemandError, DataError) as e:
        raise RecordingError(f"{e} (finished episodes are kept in {partial}; --resume continues)") from e
    except KeyboardInterrupt:
        raise RecordingInterrupted(partial, len(entries), len(plan)) from None
    finally:
        signal.signal(signal.SIGTERM, on_sigterm)
        bar.close()

    episodes = [{"file": name, **spec_entry(replace(spec, routes=spec.routes and os.path.relpath(spec.routes, out)))}
                for _, name, spec in plan]
    manifest = write_manifest(partial, [net_entry(n.path, out, n.name) for n in nets],
                              [entries[name] for _, name, _ in plan], seed=seed, disc=disc,
                              episodes=episodes)
    os.remove(plan_file)
    if os.path.isdir(out):
        os.rmdir(out)  # exists but empty (checked above)
    owner.rename(out)
    return manifest


__all__ = ["RecordingError", "RecordingInterrupted", "record_dataset"]
