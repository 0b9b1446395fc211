"""The on-disk cache of read networks (map/network.py): the same network as reading the file, read
again when the file changes, never written beside the user's file, and no error where it cannot be written."""
from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
import shapely

from sumo_scendiff.map.network import Network
from sumo_scendiff.map.network_cache import cache_entry


def written(path: str, key: tuple) -> bool:
    """Whether the cache entry at ``path`` holds ``key``: a forked process writes it while the load
    returns, so wait for it (it is renamed into place whole)."""
    import pickle
    import time
    for _ in range(600):
        try:
            with open(path, "rb") as f:
                if pickle.load(f) == key:
                    return True
        except (OSError, pickle.UnpicklingError, EOFError):
            pass
        time.sleep(0.1)
    return False


@pytest.fixture
def cache_home(tmp_path, monkeypatch):
    """An empty on-disk cache, and no network held by the process (an earlier test's, still alive,
    would be handed back without the disk being read)."""
    import weakref

    from sumo_scendiff.map import network
    home = tmp_path / "cache-home"
    monkeypatch.setenv("XDG_CACHE_HOME", str(home))
    monkeypatch.setattr(network, "_HELD", weakref.WeakValueDictionary())
    return home


def _same(a: Network, b: Network) -> None:
    assert [ln.id for ln in a.lanes] == [ln.id for ln in b.lanes]
    for x, y in zip(a.lanes, b.lanes):
        assert np.array_equal(x.shape, y.shape) and x.width == y.width and x.car == y.car and x.tls == y.tls
        assert shapely.equals_exact(x.polygon, y.polygon, 0.0)
    assert [j.id for j in a.junctions] == [j.id for j in b.junctions]
    assert a.successors == b.successors and a.shared_lanes == b.shared_lanes
    assert [(k.tls, k.lane, k.via) for k in a.signal_links] == [(k.tls, k.lane, k.via) for k in b.signal_links]


def test_a_cached_network_is_the_file_read_again(cache_home, cross2_net):
    read = Network.load(cross2_net, cache=False)
    first = Network.load(cross2_net)                   # reads the file, writes the entry
    entry = cache_entry(cross2_net)
    assert written(entry.path, entry.key) and entry.path.startswith(str(cache_home))
    _same(read, first)
    # while this process holds it, loading the same path again is that object (the studio's runs)
    assert Network.load(cross2_net) is first and Network.load(os.path.relpath(cross2_net)) is not first
    del first
    cached = Network.load(cross2_net)                  # from the entry
    _same(read, cached)
    # sumolib's net works as readNet leaves it: routing (its cache on) and unknown edge types
    snet = cached.sumo_net
    route, cost = snet.getShortestPath(snet.getEdge("wc"), snet.getEdge("ce"))
    assert [e.getID() for e in route] == ["wc", "ce"] and cost > 0
    assert snet.getEdgeType("no-such-type").id == "DEFAULT_EDGETYPE"


def test_a_changed_file_is_read_again(cache_home, tmp_path, cross_net, cross2_net):
    path = tmp_path / "user" / "city.net.xml"
    path.parent.mkdir()
    shutil.copyfile(cross_net, path)
    one = Network.load(str(path))
    assert written(cache_entry(str(path)).path, cache_entry(str(path)).key)
    shutil.copyfile(cross2_net, path)                  # the user rebuilt the network: new size and time
    two = Network.load(str(path))
    assert len(two.lanes) == len(Network.load(cross2_net, cache=False).lanes) != len(one.lanes)
    assert sorted(os.listdir(path.parent)) == ["city.net.xml"]      # nothing written beside it


def test_a_broken_entry_is_replaced(cache_home, cross_net):
    Network.load(cross_net)
    entry = cache_entry(cross_net)
    assert written(entry.path, entry.key)
    with open(entry.path, "wb") as f:
        f.write(b"\x80\x05 not a pickle")
    net = Network.load(cross_net)
    _same(net, Network.load(cross_net, cache=False))
    assert written(entry.path, entry.key)


def test_a_cache_that_cannot_be_written_is_no_error(tmp_path, monkeypatch, cross_net):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker / "below"))    # a folder below a file: no such folder
    net = Network.load(cross_net)
    assert len(net.lanes) == len(Network.load(cross_net, cache=False).lanes)
    assert not os.path.exists(cache_entry(cross_net).path)
    assert not any(p.name.endswith(".partial") for p in tmp_path.rglob("*"))
