"""The warm-up states cache's key holds everything that changes SUMO's traffic up to T (sim/warmup.py):
the seed the warm-up runs with and its options on random numbers, and the contents of every input file,
those a route file includes among them. Keys only: no SUMO run."""
from __future__ import annotations

from sumo_scendiff.sim.sumo import SimConfig
from sumo_scendiff.sim.warmup import state_key, warm_config


def _scenario(tmp_path, **kw) -> SimConfig:
    (tmp_path / "n.net.xml").write_text("<net/>\n")
    (tmp_path / "more.rou.xml").write_text('<routes><vehicle id="v" depart="0" route="r"/></routes>\n')
    (tmp_path / "d.rou.xml").write_text('<routes>\n  <include href="more.rou.xml"/>\n</routes>\n')
    return warm_config(SimConfig(net=str(tmp_path / "n.net.xml"), routes=(str(tmp_path / "d.rou.xml"),), **kw))


def test_the_key_holds_the_seed_and_the_random_options(tmp_path):
    key = state_key(_scenario(tmp_path, seed=23423), 100.0)
    assert state_key(_scenario(tmp_path, seed=42), 100.0) != key
    assert state_key(_scenario(tmp_path, seed=23423, extra=("--random", "true")), 100.0) != key
    assert state_key(_scenario(tmp_path, seed=23423, extra=("--thread-rngs", "4")), 100.0) != key


def test_the_key_follows_an_included_files_contents(tmp_path):
    cfg = _scenario(tmp_path)
    key = state_key(cfg, 100.0)
    (tmp_path / "more.rou.xml").write_text('<routes><vehicle id="v" depart="5" route="r"/></routes>\n')
    assert state_key(cfg, 100.0) != key
