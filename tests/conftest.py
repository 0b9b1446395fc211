"""Shared fixtures: tiny SUMO networks built with netconvert from plain XML (real SUMO, small scale)."""
from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import tempfile

import pytest

# the project's caches (read networks, warm-up states, OpenDRIVE) in a folder of the test session's own,
# not the user's ~/.cache; subprocesses inherit it
_CACHE = tempfile.mkdtemp(prefix="scendiff-test-cache-")
os.environ["XDG_CACHE_HOME"] = _CACHE
atexit.register(shutil.rmtree, _CACHE, True)
# under pytest-xdist (-n) the workers share the cores: one BLAS thread each, as oversubscribed threads slow
# every torch test; set before any test module imports torch
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
# torch.compile is a no-op in the tests (and their subprocesses) but those of tests/test_train_compile.py,
# which hold the compiled step equal to eager's: a first compile costs minutes of a clean machine's CPU in
# every training test that would otherwise reach it
os.environ.setdefault("TORCH_COMPILE_DISABLE", "1")


def netconvert(nodes: str, edges: str, out: str, *extra: str, turnarounds: bool = False) -> str:
    import sumo
    d = os.path.dirname(out)
    nod, edg = os.path.join(d, "n.nod.xml"), os.path.join(d, "e.edg.xml")
    with open(nod, "w") as f:
        f.write(f"<nodes>{nodes}</nodes>")
    with open(edg, "w") as f:
        f.write(f"<edges>{edges}</edges>")
    subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "netconvert"), "-n", nod, "-e", edg, "-o", out,
                    *([] if turnarounds else ["--no-turnarounds"]), "--offset.disable-normalization", "true", *extra],
                   check=True, capture_output=True)
    return out


@pytest.fixture(scope="session")
def diagonal_net(tmp_path_factory) -> str:
    """One 2-lane road from (0, 0) to (300, 300): heading 45 deg (SUMO angle 45, yaw pi/4)."""
    d = tmp_path_factory.mktemp("diag")
    return netconvert('<node id="a" x="0" y="0"/><node id="b" x="300" y="300"/>',
                      '<edge id="ab" from="a" to="b" numLanes="2" speed="13.89"/>',
                      str(d / "diag.net.xml"))


def crossing(path: str, lanes: int, turnarounds: bool = False) -> str:
    """A traffic-light crossing of two 2-way roads with ``lanes`` lanes a direction, 200 m arms,
    centred on (0, 0); with ``turnarounds`` each arm's U-turn too (netconvert's default)."""
    nodes = ('<node id="c" x="0" y="0" type="traffic_light"/>'
             '<node id="w" x="-200" y="0"/><node id="e" x="200" y="0"/>'
             '<node id="s" x="0" y="-200"/><node id="n" x="0" y="200"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="{lanes}" speed="13.89"/>'
                    for a, b in (("w", "c"), ("c", "w"), ("e", "c"), ("c", "e"),
                                 ("s", "c"), ("c", "s"), ("n", "c"), ("c", "n")))
    return netconvert(nodes, edges, path, turnarounds=turnarounds)


@pytest.fixture(scope="session")
def cross_net(tmp_path_factory) -> str:
    """A traffic-light crossing of two 2-way roads, one lane a direction (:func:`crossing`)."""
    return crossing(str(tmp_path_factory.mktemp("cross") / "cross.net.xml"), 1)


@pytest.fixture(scope="session")
def cross2_net(tmp_path_factory) -> str:
    """The crossing with two lanes a direction: its left turns wait inside the junction (two
    internal lanes per left turn, an internal junction between them)."""
    return crossing(str(tmp_path_factory.mktemp("cross2") / "cross2.net.xml"), 2)


@pytest.fixture(scope="session")
def left_lane_net(tmp_path_factory) -> str:
    """A light at c whose two-lane approach wc (60 m) turns left from its left lane alone, the
    edge w0w (240 m) before it, and the crossing's other arms."""
    nodes = ('<node id="c" x="0" y="0" type="traffic_light"/><node id="w" x="-60" y="0" type="priority"/>'
             '<node id="w0" x="-300" y="0"/><node id="e" x="200" y="0"/><node id="s" x="0" y="-200"/>'
             '<node id="n" x="0" y="200"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="2" speed="13.89"/>'
                    for a, b in (("w0", "w"), ("w", "w0"), ("w", "c"), ("c", "w"), ("e", "c"), ("c", "e"),
                                 ("s", "c"), ("c", "s"), ("n", "c"), ("c", "n")))
    return netconvert(nodes, edges, str(tmp_path_factory.mktemp("left") / "left.net.xml"))


@pytest.fixture(scope="session")
def priority_net(tmp_path_factory) -> str:
    """A junction without a light: a major road w-e (priority 2) crossed by a minor one s-n
    (priority 1), one lane each way, 300 m arms."""
    nodes = ('<node id="c" x="0" y="0" type="priority"/><node id="w" x="-300" y="0"/><node id="e" x="300" y="0"/>'
             '<node id="s" x="0" y="-300"/><node id="n" x="0" y="300"/>')
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" numLanes="1" speed="13.89" priority="{p}"/>'
                    for a, b, p in (("w", "c", 2), ("c", "w", 2), ("e", "c", 2), ("c", "e", 2),
                                    ("s", "c", 1), ("c", "s", 1), ("n", "c", 1), ("c", "n", 1)))
    return netconvert(nodes, edges, str(tmp_path_factory.mktemp("priority") / "priority.net.xml"))


@pytest.fixture(scope="session")
def city():
    """networks/city.net.xml, the shipped city, loaded once."""
    from sumo_scendiff.map.network import Network
    return Network.load(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                     "networks", "city.net.xml"))


@pytest.fixture(scope="session")
def gen():
    """The shipped generator, loaded once."""
    from sumo_scendiff.generation.generator import ScenarioGenerator
    return ScenarioGenerator.load()


@pytest.fixture(scope="session")
def grid(tmp_path_factory):
    """netgenerate's 3x3 grid with 100 m blocks (0..200 m), loaded as a Network."""
    import sumo

    from sumo_scendiff.map.network import Network
    out = str(tmp_path_factory.mktemp("grid") / "grid.net.xml")
    subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "netgenerate"), "--grid", "--grid.number", "3",
                    "--grid.length", "100", "-o", out], check=True, capture_output=True)
    return Network.load(out)


def _cross_scene(net):
    """Five agents on ``cross_net``: a queue of two (1 m bumper gap) eastbound, one northbound, one
    in the junction turning, one off the road (refused)."""
    import math

    import numpy as np

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import Scene

    east = next(ln for ln in net.lanes if ln.edge == "wc")
    north = next(ln for ln in net.lanes if ln.edge == "sc")
    turn = next(ln for ln in net.lanes if ln.internal and ln.car and len(ln.shape) > 3)
    ye, xn = float(east.shape[0][1]), float(north.shape[0][0])
    mid = len(turn.shape) // 2
    d = turn.shape[mid + 1] - turn.shape[mid]
    tyaw = math.atan2(d[1], d[0])
    boxes = [[-60.0, ye, 0.0, 4.6, 1.8], [-65.6, ye, 0.0, 4.6, 1.8], [xn, -80.0, math.pi / 2, 5.1, 1.95],
             [*turn.shape[mid], tyaw, 4.6, 1.8], [-60.0, -40.0, 0.0, 4.6, 1.8]]
    speeds = [0.0, 0.0, 8.0, 3.0, 5.0]
    boxes = np.array(boxes)
    traj = np.zeros((5, 5, 3))
    for i, (x, y, yaw, _, _) in enumerate(boxes):
        for k, t in enumerate(range(-2, 3)):
            traj[i, k] = (x + speeds[i] * t * math.cos(yaw), y + speeds[i] * t * math.sin(yaw), yaw)
    mask = np.ones((5, 5), bool)
    mask[3, 3:] = False  # the turning agent's future unknown
    return Scene(Window(0.0, 0.0, 0.0), boxes, traj, mask, np.repeat(np.array(speeds)[:, None], 5, 1),
                 np.zeros(5), "cross")


@pytest.fixture(scope="session")
def cross_scene():
    """``cross_scene(net) -> Scene``: see :func:`_cross_scene`."""
    return _cross_scene
