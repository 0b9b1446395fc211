"""A state holding a rail signal's sub-driveway (sim/state.py): libsumo survives starting from it again
and again in one process; stock SUMO, which loads the saved file itself, drives the same without them."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from .conftest import netconvert

TRACK = "allow=\"rail\" spreadType=\"center\" numLanes=\"1\" speed=\"30\""
# one bidirectional track, two rail signals; trains that depart inside a block (departPos)
TRAINS = ('<routes><vType id="train" vClass="rail" length="50"/>'
          '<vehicle id="t1" type="train" depart="0" departPos="100"><route edges="AB BC CD DE"/></vehicle>'
          '<vehicle id="t2" type="train" depart="0" departPos="200"><route edges="-DE -CD -BC -AB"/></vehicle>'
          '<vehicle id="t3" type="train" depart="5" departPos="300"><route edges="BC CD DE"/></vehicle>'
          '<vehicle id="t4" type="train" depart="5" departPos="250"><route edges="-BC -AB"/></vehicle></routes>')


@pytest.fixture(scope="module")
def rail(tmp_path_factory):
    """(net, routes, state): SUMO's own state at 30 s, with a ``<subDriveWay>`` in it."""
    import sumo
    d = tmp_path_factory.mktemp("rail")
    xs = {"A": 0, "B": 400, "C": 800, "D": 1200, "E": 1600}
    nodes = "".join(f'<node id="{n}" x="{x}" y="0" type="{"rail_signal" if n in "BC" else "priority"}"/>'
                    for n, x in xs.items())
    # single track A..D; beyond D one track each way (-DE beside DE, not its bidi)
    edges = "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" {TRACK}/><edge id="-{a}{b}" from="{b}" to="{a}" '
                    + (TRACK if a != "D" else TRACK.replace(' spreadType="center"', "")) + "/>"
                    for a, b in zip("ABCD", "BCDE"))
    net = netconvert(nodes, edges, str(d / "rail.net.xml"), turnarounds=True)
    routes = d / "r.rou.xml"
    routes.write_text(TRAINS)
    state = str(d / "state.xml.gz")
    subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "sumo"), "-n", net, "-r", str(routes), "--no-step-log",
                    "--no-warnings", "--save-state.times", "30", "--save-state.files", state, "-e", "31"],
                   check=True, capture_output=True)
    return net, str(routes), state


def test_libsumo_starts_from_the_state_again_and_again(rail):
    """SUMO 1.28's libsumo segfaults on the fourth start from such a state as it saved it."""
    import gzip
    net, routes, state = rail
    assert b"<subDriveWay " in gzip.open(state).read()
    code = ("import sys\nfrom sumo_scendiff.sim.sumo import SimConfig, close, start\n"
            f"cfg = SimConfig({net!r}, routes=({routes!r},), step_length=1.0, state={state!r})\n"
            "for k in range(6):\n    sim = start(cfg)\n    sim.simulationStep()\n"
            "    assert set(sim.vehicle.getIDList()) == {'t1', 't3'}, sim.vehicle.getIDList()\n    close(sim)\n"
            "print('six starts')\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "six starts" in done.stdout, (done.returncode, done.stderr[-2000:])
    assert b"<subDriveWay " in gzip.open(state).read()    # the saved state is as SUMO wrote it


def test_stock_sumo_drives_the_same_without_the_sub_driveways(rail, tmp_path):
    """What libsumo loads (the copy) and what stock SUMO loads (the file): the same trajectories."""
    import sumo

    from sumo_scendiff.sim.state import in_process_state
    net, routes, state = rail
    copy = in_process_state(state)
    assert copy != state and in_process_state(state) == copy
    fcd = []
    for k, s in enumerate((state, copy)):
        out = tmp_path / f"fcd{k}.xml"
        subprocess.run([os.path.join(sumo.SUMO_HOME, "bin", "sumo"), "-n", net, "-r", routes, "--load-state", s,
                        "--fcd-output", str(out), "--no-step-log", "--no-warnings", "-e", "200"],
                       check=True, capture_output=True)
        fcd.append(out.read_text().split("-->", 1)[1])     # the header names the files
    assert "<vehicle" in fcd[0] and fcd[0] == fcd[1]
