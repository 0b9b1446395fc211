"""Read networks kept on disk (map/network.py's :meth:`Network.load`): one entry per network file,
valid while the file keeps its real path, size and modification time, never beside the user's file.

    entry = cache_entry(path)          # None when the file cannot be stat'ed
    parts = read_entry(entry)          # (lanes, junctions, sumolib net), or None: read the file
    write_entry(network, entry)        # by a forked process on Linux: nobody waits for it
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass

# A new layout of what is cached (the Lane and Junction fields, sumolib's net) takes a new version
CACHE_VERSION = 2     # 2: a zero-length lane's footprint is a disc, not empty
# sumolib's net is a graph whose nodes, edges, lanes and connections refer to each other, and pickle
# descends one C call per reference: a 9 000-lane city needs a deeper stack than a thread's default
_DUMP_STACK = 1 << 28
_DUMP_DEPTH = 1_000_000


def cache_dir() -> str:
    """Where read networks are kept (core.files.cache_dir)."""
    from ..core.files import cache_dir as project_cache
    return project_cache("networks")


@dataclass(frozen=True)
class CacheEntry:
    path: str        # the entry's file
    key: tuple       # what the network file must still be for the entry to hold: its path, size, mtime


def cache_entry(path: str) -> CacheEntry | None:
    """The cache entry of network file ``path``: one file per real path, valid while the file keeps
    its size and modification time (and this code its :data:`CACHE_VERSION` and sumolib its
    version). None when the file cannot be stat'ed."""
    import hashlib

    import sumolib
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except OSError:
        return None
    name = hashlib.sha256(real.encode()).hexdigest()[:32]
    key = (real, st.st_size, st.st_mtime_ns, CACHE_VERSION, getattr(sumolib, "__version__", ""))
    return CacheEntry(os.path.join(cache_dir(), f"{name}.pkl"), key)


def read_entry(entry: CacheEntry) -> tuple | None:
    """(lanes, junctions, sumolib net) kept in ``entry`` if it is still the file's, else None (a
    missing, stale or unreadable entry is read again from the network file)."""
    import pickle
    try:
        with open(entry.path, "rb") as f:
            if pickle.load(f) != entry.key:
                return None
            lanes, junctions, sumo_net = pickle.load(f)
    except Exception:   # a half-written, truncated or foreign file: read the network again
        return None
    _thaw_sumo_net(sumo_net)
    return lanes, junctions, sumo_net


def write_entry(network, entry: CacheEntry) -> None:
    """Keep ``network`` in ``entry``, written by a forked copy of this process where the system
    forks safely (Linux), so that the first run on a network does not wait for it; else here."""
    if not sys.platform.startswith("linux"):
        _write_entry(network, entry)
        return
    pid = os.fork()
    if pid == 0:
        try:      # the child forks the writer and ends at once: nobody waits for the writer
            if os.fork() == 0:
                _write_entry(network, entry)
        finally:
            os._exit(0)
    os.waitpid(pid, 0)


def _write_entry(network, entry: CacheEntry) -> None:
    """Write ``entry`` (whole under another name, then renamed); a cache that cannot be written
    (a read-only home, a full disk) is no error: the next run reads the network file again."""
    import pickle
    import tempfile
    import threading

    snet = network.sumo_net
    routing = snet is not None and getattr(snet, "_routingCache", None) is not None
    if snet is not None:    # lambdas pickle cannot name; put back by _thaw_sumo_net
        snet._edgeTypes, snet._routingCache = dict(snet._edgeTypes), None

    def dump():
        tmp = None
        try:
            os.makedirs(os.path.dirname(entry.path), exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=os.path.dirname(entry.path), suffix=".partial")
            with os.fdopen(fd, "wb") as f:
                pickle.dump(entry.key, f, protocol=pickle.HIGHEST_PROTOCOL)
                pickle.dump((network.lanes, network.junctions, snet), f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, entry.path)
        except Exception:
            if tmp is not None and os.path.exists(tmp):
                os.remove(tmp)

    depth, stack = sys.getrecursionlimit(), threading.stack_size(_DUMP_STACK)
    sys.setrecursionlimit(max(depth, _DUMP_DEPTH))
    try:
        worker = threading.Thread(target=dump)
        worker.start()
        worker.join()
    finally:
        sys.setrecursionlimit(depth)
        threading.stack_size(stack)
    if snet is not None:
        _thaw_sumo_net(snet, routing)


def _thaw_sumo_net(snet, routing: bool = True) -> None:
    """sumolib's net as readNet leaves it: an unknown edge type is its default one, and the
    routing cache is on."""
    if snet is None:
        return
    from collections import defaultdict

    from sumolib.net import EdgeType
    snet._edgeTypes = defaultdict(lambda: EdgeType("DEFAULT_EDGETYPE", "", ""), snet._edgeTypes)
    if routing:
        snet.initRoutingCache()
