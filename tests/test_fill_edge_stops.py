"""Stops of one edge (``<stop edge=.../>``: SUMO picks the lane) in the fill's portable start, from SUMO's
own run to T: a car parked at one at T (TraCI gives it no lane, and its stop none) stays parked in
start.sumocfg as in SUMO's own run (scenario.sumocfg, the state), and a car on its way to one makes it,
each leaving within a few seconds of SUMO's own. Real SUMO, a tiny grid."""
from __future__ import annotations

import re

import pytest

from .test_fill_robust import _netgenerate

BEGIN = 300
# s: a car parked at T parks again in the portable start's second step and leaves that much late
LEAVE_S = 8.0
# a car parks 75 s at the end of B1B2 (no parking area), another line stops 20 s at the end of C2C3
ROUTES = """<routes>
  <route id="r2" edges="B0B1 B1B2 B2B3 B3C3"/><route id="r3" edges="C0C1 C1C2 C2C3 C3D3"/>
  <flow id="park" begin="5" end="900" period="30" route="r2"><stop edge="B1B2" endPos="90" duration="75" parking="true"/></flow>
  <flow id="edge" begin="10" end="900" period="20" route="r3"><stop edge="C2C3" endPos="90" duration="20"/></flow>
</routes>"""


def _stops(config: str, seconds: float) -> dict[str, tuple[float, float, bool]]:
    """stock SUMO on ``config`` for ``seconds``: per vehicle on the road or parked in its first step (its
    id without the portable start's prefix), when it first stands at a stop, when it leaves it and
    whether it parked there; only the vehicles that stood at one."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    libsumo.start([sumo_binary(), "-c", config, "--no-step-log", "true", "--no-warnings", "true"])
    try:
        libsumo.simulationStep()
        first = set(libsumo.vehicle.getIDList()) | set(libsumo.simulation.getPendingVehicles())
        end = libsumo.simulation.getTime() + seconds
        stood: dict[str, list] = {}
        while libsumo.simulation.getTime() < end:
            present = set(libsumo.vehicle.getIDList())
            for vid in first & present:
                if libsumo.vehicle.isStopped(vid) and vid not in stood:
                    stood[vid] = [libsumo.simulation.getTime(), None, libsumo.vehicle.isStoppedParking(vid)]
                elif vid in stood and stood[vid][1] is None and not libsumo.vehicle.isStopped(vid):
                    stood[vid][1] = libsumo.simulation.getTime()
            libsumo.simulationStep()
    finally:
        libsumo.close()
    return {vid.removeprefix("start."): tuple(v) for vid, v in stood.items()}


@pytest.mark.slow   # a real fill
def test_cars_at_stops_of_one_edge_keep_them_in_the_portable_start(tmp_path):
    from sumo_scendiff.fill.__main__ import get_options, main
    _netgenerate(str(tmp_path / "grid.net.xml"))
    (tmp_path / "d.rou.xml").write_text(ROUTES)
    out = tmp_path / "o"
    assert main(get_options(["-n", str(tmp_path / "grid.net.xml"), "-r", str(tmp_path / "d.rou.xml"),
                             "--begin", str(BEGIN), "-o", str(out)])) == 0
    own = _stops(str(out / "scenario.sumocfg"), 120)
    # as long again as a car may leave late: one that leaves near the end of SUMO's own window leaves in it
    portable = _stops(str(out / "start.sumocfg"), 120 + LEAVE_S)
    parked_at_t = {v for v, (t0, _, parked) in own.items() if parked and t0 <= BEGIN + 1}
    on_the_way = {v for v, (t0, _, parked) in own.items() if not parked and t0 > BEGIN + 2}
    assert len(parked_at_t) >= 2 and on_the_way, own
    assert set(own) <= set(portable)
    assert all(portable[v][2] for v in parked_at_t)            # parked again, not driven off
    # all in one step (SUMO's checks against the other cars left out: they depart at one place)
    assert len({portable[v][0] for v in parked_at_t}) == 1, {v: portable[v] for v in parked_at_t}
    late = {v: portable[v][1] - own[v][1] for v in own if own[v][1] is not None}
    assert all(abs(dt) <= LEAVE_S for dt in late.values()), late
    # the parked cars' stops on the lane SUMO parked them from, the rest of their duration
    text, rest = (out / "start.rou.xml").read_text(), []
    for vid in parked_at_t:
        car = re.search(rf'<vehicle id="start\.{re.escape(vid)}".*?</vehicle>', text, re.S)
        assert car and 'lane="B1B2_0"' in car.group(0) and 'departLane="0"' in car.group(0)
        rest.append(float(re.search(r'duration="([^"]+)"', car.group(0))[1]))
    assert max(rest) <= 75 and min(rest) < 75     # one may have parked at T itself
