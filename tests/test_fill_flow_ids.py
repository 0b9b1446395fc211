"""The demand's flows in the fill's folder number their vehicles on as SUMO's own run does: a flow whose
f.0..f.11 departed before T departs f.12 next in both starts (SUMO itself, loaded with --begin T, would
start again at f.0). Real SUMO, a tiny grid."""
from __future__ import annotations

import pytest

from .test_fill_robust import _netgenerate

BEGIN = 300
# a flow of each kind of fixed departures (period, vehsPerHour of a period SUMO rounds to ms, number
# spread over begin..end, number at a period) and a random one, which keeps its own numbering (on a
# route of its own: its vehicles differ, and would hold up others' departures differently)
ROUTES = """<routes>
  <route id="r" edges="B0B1 B1B2 B2B3 B3C3"/>
  <flow id="g" begin="0" end="900" vehsPerHour="700" from="A0A1" to="A1A2"/>
  <flow id="n" begin="3.3" end="901" number="7" route="r"/>
  <flow id="f" begin="5" end="900" period="25"><route edges="C0C1 C1C2 C2C3"/></flow>
  <flow id="m" begin="10" period="33.3" number="40" route="r"/>
  <flow id="p" begin="5" end="900" probability="0.02"><route edges="D0D1 D1D2 D2D3"/></flow>
</routes>"""


def _departed(args: list[str], until: float) -> dict[str, float]:
    """stock SUMO: vehicle id -> the time it was to depart (its departure less its delay: insertion waits
    on the traffic, whose speed factors SUMO draws in another order from a state), to ``until``."""
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    libsumo.start([sumo_binary(), *args, "--no-step-log", "true", "--no-warnings", "true"])
    out: dict[str, float] = {}
    try:
        while libsumo.simulation.getTime() < until:
            libsumo.simulationStep()
            for vid in libsumo.simulation.getDepartedIDList():
                if vid not in out:   # a car leaving a parking lot departs again
                    out[vid] = libsumo.vehicle.getDeparture(vid) - libsumo.vehicle.getDepartDelay(vid)
    finally:
        libsumo.close()
    return out


def test_departures_are_sumos():
    """A flow's departures as SUMO spaces them (ms steps; the test below checks them against SUMO)."""
    from sumo_scendiff.fill.flow_ids import departures
    assert departures({"begin": "5", "end": "900", "period": "25"})[-1] == 880_000
    assert len(departures({"begin": "0", "end": "900", "vehsPerHour": "700"})) == 175   # 5 143 ms apart
    assert departures({"begin": "3.3", "end": "901", "number": "7"})[1] == 3_300 + 128_242
    # no end: the simulation's --end where set, else a day after its begin (SUMO 1.28: y.1 at 17 380 s,
    # 19 080 s with --end 95000)
    assert departures({"begin": "100", "number": "5"})[1] == 17_380_000
    assert departures({"begin": "100", "number": "5"}, sim_end="95000")[1] == 19_080_000
    assert len(departures({"begin": "0", "period": "3600"}, sim_end="-1")) == 24
    assert departures({"begin": "0", "end": "900", "probability": "0.1"}) is None
    assert departures({"begin": "0", "period": "exp(0.1)"}) is None


@pytest.mark.slow   # a real fill
def test_flows_number_on_in_both_starts(tmp_path):
    from sumo_scendiff.fill.__main__ import get_options, main
    net = _netgenerate(str(tmp_path / "grid.net.xml"))
    (tmp_path / "d.rou.xml").write_text(ROUTES)
    out = tmp_path / "o"
    assert main(get_options(["-n", net, "-r", str(tmp_path / "d.rou.xml"), "--begin", str(BEGIN),
                             "-o", str(out)])) == 0
    until = BEGIN + 400
    own = {v: t for v, t in _departed(["-n", net, "-r", str(tmp_path / "d.rou.xml"), "--seed", "0"], until).items()
           if t >= BEGIN}
    fixed = {v for v in own if not v.startswith("p.")}
    assert {"g.59", "f.12", "n.3", "m.9"} <= fixed
    for config in ("start.sumocfg", "scenario.sumocfg"):
        replay = _departed(["-c", str(out / config)], until)
        mine = {v for v, t in replay.items() if t >= BEGIN and not v.startswith(("p.", "start."))}
        assert mine == fixed, (config, sorted(mine ^ fixed))
        assert all(abs(replay[v] - own[v]) < 1e-6 for v in fixed), config
        # the random flow departs under its own numbering, never an id of a vehicle already made
        assert not {v for v in replay if v.startswith("p.")} & {f"start.{v}" for v in replay}


@pytest.mark.slow   # a real fill
def test_a_route_file_cut_short_keeps_its_flows(tmp_path):
    """A route file cut short (SUMO runs it to where its reading reaches the cut): the fill runs, its
    flows left as given, and both starts run in stock SUMO."""
    import subprocess

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.__main__ import get_options, main
    net = _netgenerate(str(tmp_path / "grid.net.xml"))
    cut = tmp_path / "cut.rou.xml"
    cut.write_text('<routes>\n  <flow id="f" begin="5" end="900" period="25"><route edges="C0C1 C1C2 C2C3"/></flow>\n'
                   + "".join(f'  <vehicle id="v{t}" depart="{t}"><route edges="B0B1 B1B2"/></vehicle>\n'
                             for t in range(0, 3001, 100)) + '  <vehicle id="v3100" depart="3100"><route edg')
    out = tmp_path / "o"
    assert main(get_options(["-n", net, "-r", str(cut), "--begin", str(BEGIN), "-o", str(out)])) == 0
    for cfg in ("scenario.sumocfg", "start.sumocfg"):
        run = subprocess.run([sumo_binary(), "-c", str(out / cfg), "--end", str(BEGIN + 60), "--no-step-log", "true"],
                             capture_output=True, text=True)
        assert run.returncode == 0, run.stderr[-400:]


def test_a_large_route_file_is_read_in_a_stream(tmp_path):
    """A city's route file is renumbered without its DOM in memory (ElementTree's tree of it is several
    times the file): the peak Python allocation stays under the file's size, and the file is rewritten
    without its early flow, every vehicle kept."""
    import tracemalloc
    import xml.etree.ElementTree as ET

    from sumo_scendiff.fill.flow_ids import _renumber_file
    path = tmp_path / "big.rou.xml"
    with open(path, "w") as f:
        f.write('<routes>\n  <flow id="g" begin="0" end="900" period="60" from="A0A1" to="A1A2"/>\n')
        f.writelines(f'  <vehicle id="v{k}" depart="{k}"><route edges="A0A1 A1A2 A2A3"/></vehicle>\n'
                     for k in range(20000))
        f.write('</routes>\n')
    tracemalloc.start()
    try:
        found = _renumber_file(str(path), 300_000, None)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert [el.get("id") for _, el in found][:2] == ["g.5", "g.6"]
    assert peak < path.stat().st_size, (peak, path.stat().st_size)
    tags = [el.tag for el in ET.parse(path).getroot()]
    assert tags.count("vehicle") == 20000 and "flow" not in tags
