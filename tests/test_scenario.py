"""A user's SUMO scenario as shipped: .sumocfg reading, -n/-r/-a replacing it, route files as a set."""
from __future__ import annotations

import os
import shutil

import pytest

from sumo_scendiff.data.demand import DemandError, check_demand, demand_span, seeding_time
from sumo_scendiff.sim.scenario import ScenarioError, scenario_from_files

VTYPES = '<additional>\n  <vType id="slow" vClass="passenger" maxSpeed="8"/>\n</additional>\n'
ROUTES = ('<routes>\n  <vehicle id="v0" type="slow" depart="12.5"><route edges="wc ce"/></vehicle>\n'
          '  <flow id="f" begin="3" end="60" period="10" from="sc" to="cn"/>\n</routes>\n')


@pytest.fixture
def scenario(tmp_path, cross_net):
    """A DLR-TS-style folder: network, route file, vTypes in an additional file, a .sumocfg."""
    d = tmp_path / "scen"
    (d / "sub").mkdir(parents=True)
    shutil.copy(cross_net, d / "cross.net.xml")
    (d / "sub" / "cars.rou.xml").write_text(ROUTES)
    (d / "vtypes.add.xml").write_text(VTYPES)
    (d / "run.sumocfg").write_text(
        '<configuration>\n <input>\n  <net-file value="cross.net.xml"/>\n'
        '  <route-files value="sub/cars.rou.xml"/>\n  <additional-files value="vtypes.add.xml"/>\n'
        ' </input>\n <time>\n  <begin value="0:00:10"/>\n  <end value="3600"/>\n  <step-length value="1"/>\n </time>\n'
        ' <output>\n  <tripinfo-output value="trips.xml"/>\n </output>\n</configuration>\n')
    return d


def test_a_sumocfg_gives_its_inputs_relative_to_its_folder(scenario):
    s = scenario_from_files(str(scenario / "run.sumocfg"))
    assert s.net == str(scenario / "cross.net.xml")
    assert s.routes == (str(scenario / "sub" / "cars.rou.xml"),)
    assert s.additional == (str(scenario / "vtypes.add.xml"),)
    assert (s.begin, s.end) == (10.0, 3600.0)       # SUMO's H:M:S form too
    assert s.step_length == 1.0                      # run and fill take it unless --step-length


def test_flags_replace_what_the_configuration_names(scenario, tmp_path):
    other = tmp_path / "other.rou.xml"
    other.write_text(ROUTES)
    s = scenario_from_files(str(scenario / "run.sumocfg"), routes=[str(other)])
    assert s.routes == (str(other),) and s.additional == (str(scenario / "vtypes.add.xml"),)


def test_a_missing_file_names_the_configuration_the_option_and_the_file(scenario):
    os.remove(scenario / "sub" / "cars.rou.xml")
    with pytest.raises(ScenarioError, match=r"run\.sumocfg: route-files: sub/cars\.rou\.xml: no such file"):
        scenario_from_files(str(scenario / "run.sumocfg"))
    # ... and the flag that replaces it makes the configuration usable again
    (scenario / "mine.rou.xml").write_text(ROUTES)
    assert scenario_from_files(str(scenario / "run.sumocfg"), routes=[str(scenario / "mine.rou.xml")]).routes


def test_file_lists_are_read_as_sumo_reads_them(scenario):
    """Files are separated by commas (a space is part of a name, written %20 or as it is); a
    space-separated list is one file that does not exist, as SUMO says too."""
    (scenario / "my routes.rou.xml").write_text(ROUTES)
    for value in ("my routes.rou.xml, sub/cars.rou.xml", "my%20routes.rou.xml,sub/cars.rou.xml"):
        (scenario / "sp.sumocfg").write_text(f'<configuration><net-file value="cross.net.xml"/>'
                                             f'<route-files value="{value}"/></configuration>')
        assert scenario_from_files(str(scenario / "sp.sumocfg")).routes == (
            str(scenario / "my routes.rou.xml"), str(scenario / "sub" / "cars.rou.xml"))
    (scenario / "sp.sumocfg").write_text('<configuration><net-file value="cross.net.xml"/>'
                                         '<route-files value="sub/cars.rou.xml vtypes.add.xml"/></configuration>')
    with pytest.raises(ScenarioError, match=r"route-files: sub/cars\.rou\.xml vtypes\.add\.xml: no such file"):
        scenario_from_files(str(scenario / "sp.sumocfg"))


@pytest.mark.parametrize("text, message", [
    ("not xml at all <", "not a SUMO configuration"),
    ("<configuration/>", "not a SUMO configuration"),
    ('<configuration><route-files value="sub/cars.rou.xml"/></configuration>', "names no net-file"),
])
def test_bad_configurations_are_one_line(scenario, text, message):
    (scenario / "bad.sumocfg").write_text(text)
    with pytest.raises(ScenarioError, match=message) as e:
        scenario_from_files(str(scenario / "bad.sumocfg"))
    assert "\n" not in str(e.value)


def test_a_configuration_given_as_network_is_named(scenario):
    with pytest.raises(ScenarioError, match=r"-n: .*run\.sumocfg: a SUMO configuration, not a network"):
        scenario_from_files(net=str(scenario / "run.sumocfg"))


def test_a_configuration_is_read_whatever_its_name(scenario):
    # stock SUMO reads -c by content: Veins ships its configurations as .sumo.cfg (corpus: veins_erlangen)
    from sumo_scendiff.sim.scenario import input_flags_problem
    cfg = scenario / "erlangen.sumo.cfg"
    shutil.copy(scenario / "run.sumocfg", cfg)
    assert input_flags_problem(None, str(cfg)) is None
    assert scenario_from_files(str(cfg)).net == str(scenario / "cross.net.xml")
    assert "a SUMO network, not a configuration" in input_flags_problem(None, str(scenario / "cross.net.xml"))


def test_route_files_are_checked_as_a_set(scenario, cross_net):
    from sumo_scendiff.map.network import Network
    edges = {ln.edge for ln in Network.load(cross_net).lanes}
    routes, vtypes = str(scenario / "sub" / "cars.rou.xml"), str(scenario / "vtypes.add.xml")
    assert check_demand([routes], edges, additional=[vtypes]) == 3.0     # the flow begins first
    only_types = scenario / "types.rou.xml"
    only_types.write_text("<routes>" + VTYPES.split("\n")[1] + "</routes>")
    assert check_demand([str(only_types), routes], edges) == 3.0         # vTypes alone: legal in a set
    with pytest.raises(DemandError, match="no vehicle routes or trips"):
        check_demand([str(only_types)], edges)
    foreign = scenario / "foreign.rou.xml"
    foreign.write_text('<routes><vehicle id="x" depart="0"><route edges="nowhere gone"/></vehicle></routes>')
    with pytest.raises(DemandError, match="foreign.rou.xml: does not match the network"):
        check_demand([routes, str(foreign)], edges)


def test_the_demands_span_in_every_form_sumo_reads(tmp_path, cross_net):
    """Departures as seconds or clock time, attributes with spaces around '=', a flow departing
    until its end; a flow without an end departs for a day (SUMO's default), or until the
    simulation's end."""
    from sumo_scendiff.map.network import Network
    edges = sorted({ln.edge for ln in Network.load(cross_net).lanes})
    f = tmp_path / "d.rou.xml"
    f.write_text(f'<routes><flow id="f" begin= "15:00:00" end ="16:00:00" number="9" from="{edges[0]}" '
                 f'to="{edges[-1]}"/><vehicle id="v" depart="triggered"><route edges="{edges[0]}"/></vehicle>'
                 f'<trip id="t" depart="54300.5" from="{edges[0]}" to="{edges[-1]}"/></routes>')
    assert demand_span([str(f)], set(edges)) == (54000.0, 57600.0)
    assert check_demand([str(f)], set(edges)) == 54000.0
    f.write_text(f'<routes><flow id="f" begin="10" period="5" from="{edges[0]}" to="{edges[-1]}"/></routes>')
    assert demand_span([str(f)], set(edges)) == (10.0, 10.0 + 86400.0)
    assert demand_span([str(f)], set(edges), end=3600.0) == (10.0, 3600.0)


def test_the_seeding_time_is_on_sumos_clock_within_the_demand():
    """run, sweep and fill seed at one time on SUMO's clock (as sumo's -b): given, or 600 s after
    SUMO's start (the configuration's begin, not before the first departure), or at the last
    departure of a shorter demand; outside the departures (an empty or emptying network) or
    before the configuration's begin: one line naming the flag and the demand's span."""
    span, files = (25200.0, 28800.0), ["d.rou.xml"]
    assert seeding_time(None, None, span, files) == 25800.0
    assert seeding_time(None, 25000.0, span, files) == 25800.0      # the network is empty before 25200
    assert seeding_time(None, 26000.0, span, files) == 26600.0
    assert seeding_time(27000.0, None, span, files) == 27000.0
    assert seeding_time(None, None, (0.0, 200.0), files) == 200.0    # all its traffic has departed
    with pytest.raises(DemandError, match=r"^--begin 600 s \(0:10:00\) lies outside the demand \(d.rou.xml: "
                       r"departures from 25200 s \(7:00:00\) to 28800 s \(8:00:00\)\); give a --begin within it$"):
        seeding_time(600.0, None, span, files)
    with pytest.raises(DemandError, match=r"^begin 25500 s \(7:05:00\) lies before the configuration's begin "
                       r"26000 s \(7:13:20\); give a later begin$"):
        seeding_time(25500.0, 26000.0, span, files, flag="begin")
    with pytest.raises(DemandError, match=r"^the default start \(first departure \+ 600 s\) 30000 s"):
        seeding_time(None, 30000.0, span, files)
    # a begin after the last departure is SUMO's to run: a looping demand still drives then
    assert seeding_time(30000.0, None, span, files) == 30000.0
    with pytest.raises(DemandError, match=r"^--begin 30000 s \(8:20:00\) lies after the configuration's end "
                       r"29000 s \(8:03:20\); give an earlier --begin$"):
        seeding_time(30000.0, None, span, files, config_end=29000.0)


def test_a_saved_state_starts_without_the_flows_it_has_finished(tmp_path):
    """A flow whose vehicles have all departed is no longer in a saved state, but is in the route
    file SUMO loads with it: started from the state (SimConfig.state, --load-state) SUMO goes on
    with the flows still running; simulation.loadState after the start would insert the finished
    flow's first vehicle again, on the from/to it kept as a route (SUMO stops: no valid route)."""
    from dataclasses import replace

    from sumo_scendiff.sim.sumo import SimConfig, close, start
    net = os.path.join(os.path.dirname(__file__), "..", "networks", "grid3x3_1lane.net.xml")
    routes = tmp_path / "flows.rou.xml"
    routes.write_text('<routes><flow id="done" begin="0" end="5" number="1" from="A0A1" to="C1C2"/>'
                      '<flow id="going" begin="0" end="1000" period="10" from="A1A2" to="C2C1"/></routes>')
    cfg = SimConfig(net=net, routes=(str(routes),), begin=0.0)
    sim = start(cfg)
    try:
        for _ in range(240):
            sim.simulationStep()
        sim.simulation.saveState(str(tmp_path / "state.xml.gz"))
    finally:
        close(sim)
    sim = start(replace(cfg, state=str(tmp_path / "state.xml.gz")))
    try:
        departed = []
        for _ in range(40):
            sim.simulationStep()
            departed += sim.simulation.getDepartedIDList()
        assert sim.simulation.getTime() == 140.0 and departed == ["going.12", "going.13"]
    finally:
        close(sim)


def test_a_scenario_sumo_refuses_is_one_line_naming_its_error(tmp_path, cross_net, capfd):
    """SUMO refusing to load (a light's program that does not fit the junction) raises SimError
    with SUMO's own first error as the message, and nothing of SUMO's reaches the terminal."""
    from sumo_scendiff.sim.sumo import SimConfig, SimError, close, start
    bad = tmp_path / "bad.add.xml"
    bad.write_text('<additional><tlLogic id="c" type="static" programID="x" offset="0">'
                   '<phase duration="30" state="Gr"/></tlLogic></additional>')
    with pytest.raises(SimError, match=r"^SUMO refused to start: Mismatching phase size in tls 'c'"):
        start(SimConfig(net=cross_net, additional=(str(bad),)))
    assert "Error" not in capfd.readouterr().err
    close(start(SimConfig(net=cross_net)))          # libsumo starts again after a refusal


def test_the_configurations_run_options_are_carried(tmp_path, grid):
    """A .sumocfg's options on how SUMO runs its demand (here --junction-taz, which its
    fromJunction flow needs, a teleport time and rerouting) reach every SUMO run and exported
    configuration; its outputs, reports, GUI settings, seed and step length do not."""
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    routes = tmp_path / "junc.rou.xml"
    routes.write_text('<routes><flow id="j" fromJunction="A0" toJunction="C2" begin="0" end="60" period="5"/></routes>')
    cfg = tmp_path / "junc.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{grid.path}"/><route-files value="{routes}"/></input>'
                   '<output><tripinfo-output value="ti.xml"/></output><time><begin value="0"/><step-length value="1"/>'
                   '</time><processing><junction-taz value="true"/><time-to-teleport value="120"/></processing>'
                   '<routing><device.rerouting.probability value="0.5"/></routing><report><verbose value="true"/>'
                   '</report><random_number><seed value="7"/></random_number><gui_only><start value="true"/>'
                   '</gui_only></configuration>')
    scen = scenario_from_files(str(cfg))
    assert scen.options == (("junction-taz", "true"), ("time-to-teleport", "120"),
                            ("device.rerouting.probability", "0.5"))
    sim_cfg = SimConfig(net=scen.net, routes=scen.routes, begin=0.0, scenario_options=scen.options)
    args = sim_cfg.args()
    assert args.count("--time-to-teleport") == 1 and args[args.index("--time-to-teleport") + 1] == "120"
    assert sim_cfg.options()["junction-taz"] == "true" and sim_cfg.options()["step-length"] == "0.5"
    sim = start(sim_cfg)
    try:
        sim.simulationStep(30.0)
        assert sim.vehicle.getIDCount() > 0
    finally:
        close(sim)


def test_options_outside_any_section_go_by_the_section_sumo_files_them_under(tmp_path, grid):
    """SUMO reads an option given outside any section too (sumo-rl's configurations give their TraCI
    port so): a TraCI port, a seed or a GUI option there is not carried (an in-process run would wait
    for a TraCI client), a processing option is."""
    cfg = tmp_path / "traci.sumocfg"
    cfg.write_text(f'<configuration><net-file value="{grid.path}"/><remote-port value="8813"/>'
                   '<num-clients value="1"/><seed value="3"/><start value="true"/>'
                   '<time-to-teleport value="-1"/></configuration>')
    assert scenario_from_files(str(cfg)).options == (("time-to-teleport", "-1"),)


def test_how_strictly_sumo_reads_the_files_is_carried(tmp_path, grid):
    """A configuration's xml-validation (a report option) decides whether SUMO loads its files at all
    (SUMO's bicycle game gives flows a beginLane its schema does not declare): carried, unlike the
    other report options."""
    cfg = tmp_path / "v.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{grid.path}"/></input><report>'
                   '<verbose value="true"/><xml-validation value="never"/></report></configuration>')
    assert scenario_from_files(str(cfg)).options == (("xml-validation", "never"),)


def test_sumos_other_names_for_its_inputs_are_read(scenario):
    """SUMO takes ``net``, ``routes`` and ``additional`` for its input options (MSFrame's synonyms) under any
    root (sumolib's RiLSA examples: ``<c><net value=.../>``): the same inputs, none carried as a run option."""
    (scenario / "c.sumo.cfg").write_text(
        '<c>\n  <net value="cross.net.xml"/>\n  <routes value="sub/cars.rou.xml"/>\n'
        '  <additional value="vtypes.add.xml"/>\n  <b value="10"/>\n</c>\n')
    s = scenario_from_files(str(scenario / "c.sumo.cfg"))
    assert s.net == str(scenario / "cross.net.xml") and s.routes == (str(scenario / "sub" / "cars.rou.xml"),)
    assert s.additional == (str(scenario / "vtypes.add.xml"),) and s.begin == 10.0 and s.options == ()
    # a flag replaces the file whichever name the configuration gives it
    assert scenario_from_files(str(scenario / "c.sumo.cfg"), routes=[str(scenario / "sub" / "cars.rou.xml")])
