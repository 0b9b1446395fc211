"""The scenario's own fleet (sim/fleet.py): with a demand every seeded vehicle is of one of its vTypes."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sumo_scendiff.map.network import Network
from sumo_scendiff.sim.fleet import DRAWN_KEY, Fleet, own_size
from sumo_scendiff.sim.seeding import Seeder
from sumo_scendiff.tokens.file import TokenFileError

TYPES = """<additional>
    <vType id="car" vClass="passenger" length="4.3" width="1.7" minGap="1.5" accel="2.2" decel="4.0"
           emissionClass="HBEFA4/PC_petrol_Euro-6ab"/>
    <vType id="coach" vClass="bus" length="12.0" width="2.55" minGap="2.0" accel="1.0" decel="3.5"
           emissionClass="HBEFA4/UBus_Std_gt15-18t_Euro-VI_A-C"/>
</additional>
"""
# as many coaches as cars depart: a coach is seeded wherever there is room for one
DEMAND = """<routes>
    <flow id="cars" type="car" begin="0" end="100" period="6" from="wc" to="ce"/>
    <flow id="coaches" type="coach" begin="0" end="100" period="6" from="sc" to="cn"/>
</routes>
"""
OWN = {"car": ("passenger", 4.3, 1.7, 1.5, 2.2, "HBEFA4/PC_petrol_Euro-6ab"),
       "coach": ("bus", 12.0, 2.55, 2.0, 1.0, "HBEFA4/UBus_Std_gt15-18t_Euro-VI_A-C")}


@pytest.fixture(scope="module")
def scenario(cross_net, tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    (d / "types.add.xml").write_text(TYPES)
    (d / "demand.rou.xml").write_text(DEMAND)
    return cross_net, str(d / "types.add.xml"), str(d / "demand.rou.xml")


def _seed(scenario, cross_scene, seed: int, types=None, demand: bool = True, tweak=None, sized=None):
    """Start SUMO on the scenario (its demand run 40 s), seed the five-agent crossing scene (changed
    by ``tweak(scene)``); returns per seeded agent (its vType as SUMO has it), the scene, the report
    and the fleet."""
    import libsumo as sim
    net_path, add, rou = scenario
    net = Network.load(net_path)
    scene = cross_scene(net)
    if tweak is not None:
        tweak(scene)
    sim.start(["sumo", "-n", net_path, "-a", add, "--no-step-log", "--no-warnings"]
              + (["-r", rou] if demand else []))
    try:
        for _ in range(40 if demand else 0):
            sim.simulationStep()
        seeder = Seeder(sim, net, seed=seed)
        report = seeder.seed(scene, types=types, sized=sized)
        sim.simulationStep()
        seeder.verify(report)
        t = sim.vehicletype
        got = {i: (t.getVehicleClass(tid), t.getLength(tid), t.getWidth(tid), t.getMinGap(tid), t.getAccel(tid),
                   t.getEmissionClass(tid))
               for i, tid in ((i, sim.vehicle.getTypeID(v)) for i, v in report.ids.items())}
        return got, scene, report, seeder.fleet
    finally:
        sim.close()


def test_every_seeded_vehicle_is_one_of_the_scenarios_vtypes(scenario, cross_scene):
    got, scene, report, fleet = _seed(scenario, cross_scene, seed=0)
    assert fleet.active and set(fleet.share) == {"car", "coach"}
    assert report.placed == 4 and not report.misplaced
    for i, (cls, length, width, min_gap, accel, emission) in got.items():
        name = scene.meta[DRAWN_KEY][i][0]
        own = OWN[name]
        assert (cls, length, width, accel, emission) == (own[0], own[1], own[2], own[4], own[5])
        assert min_gap <= own[3] + 1e-9          # a copy that differs by minGap only where it must fit
        assert tuple(scene.boxes[i, 3:5]) == pytest.approx((own[1], own[2]))
    # the queue of two 1 m apart has no room for a coach, whatever the seed
    assert {scene.meta[DRAWN_KEY][i][0] for i in (0, 1)} == {"car"}
    assert got[1][3] < OWN["car"][3]             # the follower keeps a minGap that fits its gap


def test_coaches_where_they_fit_and_the_same_seed_the_same_fleet(scenario, cross_scene):
    names = []
    for seed in (0, 1, 2, 3, 0):
        _, scene, report, _ = _seed(scenario, cross_scene, seed=seed)
        names.append([scene.meta[DRAWN_KEY][i][0] for i in sorted(report.ids)])
        assert not report.misplaced
    assert names[0] == names[-1]
    assert any("coach" in n for n in names) and all(n[:2] == ["car", "car"] for n in names)


def test_no_vtype_fits_a_queue_drawn_tighter_than_its_cars(scenario, cross_scene):
    """Two 4 m cars drawn 0.1 m apart: as the scenario's 4.3 m cars (centres kept) they would
    overlap, so one is not seeded, with the reason; the drawn boxes are kept in the record."""
    def tight(scene):
        scene.boxes[:2, 3] = 4.0
        scene.boxes[1, 0] = scene.boxes[0, 0] - 4.1
        scene.traj[1, :, 0] = scene.boxes[1, 0]
    got, scene, report, _ = _seed(scenario, cross_scene, seed=0, tweak=tight)
    assert len({0, 1} & set(report.conflicts)) == 1 and len({0, 1} & set(report.ids)) == 1
    why = report.conflicts[min(set(report.conflicts) & {0, 1})]
    assert "as vType 'car' its box overlaps" in why
    assert scene.meta[DRAWN_KEY][0][1] == pytest.approx(4.0) and scene.boxes[0, 3] == pytest.approx(4.3)


def test_a_named_vtype_is_given_and_unknown_names_are_one_line(scenario, cross_scene):
    got, scene, report, fleet = _seed(scenario, cross_scene, seed=0, types=[None, None, "coach", "car", None])
    assert got[2][:3] == ("bus", 12.0, 2.55) and got[3][:3] == ("passenger", 4.3, 1.7)
    # a token's vtype: its size where the token gives none, the token's own where it does
    toks = fleet.token_vtypes([{"x": 1.0, "y": 0.0, "vtype": "coach"},
                               {"x": 5.0, "y": 0.0, "vtype": "car", "length": 4.0, "width": 1.6}, {"x": 9.0}],
                              "tok.toml")
    assert (toks[0]["length"], toks[0]["width"]) == (12.0, 2.55) and toks[1]["length"] == 4.0
    with pytest.raises(TokenFileError) as e:
        fleet.token_vtypes([{"x": 1.0}, {"vtype": "bus_articulated"}], "tok.toml")
    msg = str(e.value)
    assert msg.startswith("tok.toml: agents[1]") and "'bus_articulated'" in msg and "\n" not in msg


def test_a_token_that_gives_a_size_is_seeded_at_that_size(scenario, cross_scene):
    """A user's token 10.5 x 2.5 m (a truck) is not given a car drawn from the mix: SUMO's vehicle has
    the token's size, as the scenario's type nearest it (the coach), whatever the seed."""
    def truck(scene):
        scene.boxes[2, 3:5] = (10.5, 2.5)
    for seed in (0, 1, 2, 3):
        got, scene, report, _ = _seed(scenario, cross_scene, seed=seed, tweak=truck,
                                      sized=[None, None, "size", None, None])
        assert got[2][:3] == pytest.approx(("bus", 10.5, 2.5)) and got[2][4:] == OWN["coach"][4:]
        assert tuple(scene.boxes[2, 3:5]) == pytest.approx((10.5, 2.5)) and scene.meta[DRAWN_KEY][2][0] == "coach"
    # which user tokens keep their size (the co-simulation passes it per agent)
    assert [own_size(t) for t in ({"x": 1.0, "length": 10.5, "width": 2.5}, {"vclass": "truck"},
                                  {"vtype": "car", "length": 4.0}, {"x": 1.0, "speed": 3.0})] == ["size", "class", None, None]


def test_a_bare_network_keeps_the_drawn_boxes(scenario, cross_scene):
    got, scene, report, fleet = _seed(scenario, cross_scene, seed=0, demand=False)
    assert not fleet.active and not scene.meta.get(DRAWN_KEY)
    assert got[2][:2] == pytest.approx(("passenger", 5.1)) and got[0][1] == pytest.approx(4.6)


def _fleet_of(cross_net, tmp_path, routes: str, before=None, **read) -> Fleet:
    """The fleet of SUMO on the crossing with ``routes`` (a route file's text), after ``before(sim)``."""
    import libsumo as sim
    (tmp_path / "d.rou.xml").write_text(routes)
    sim.start(["sumo", "-n", cross_net, "-r", str(tmp_path / "d.rou.xml"), "--no-step-log", "--no-warnings"])
    try:
        if before is not None:
            before(sim)
        return Fleet.read(sim, **read)
    finally:
        sim.close()


def test_a_distribution_is_shared_by_its_probabilities(cross_net, tmp_path):
    """A demand of one vTypeDistribution: the mix is its members', by their probabilities."""
    import libsumo as sim
    (tmp_path / "d.rou.xml").write_text(
        '<routes><vTypeDistribution id="mix"><vType id="a" length="4" probability="3"/>'
        '<vType id="b" length="6" vClass="delivery" probability="1"/></vTypeDistribution>'
        '<flow id="f" type="mix" begin="0" end="10" period="1" from="wc" to="ce"/></routes>')
    sim.start(["sumo", "-n", cross_net, "-r", str(tmp_path / "d.rou.xml"), "--no-step-log", "--no-warnings"])
    try:
        fleet = Fleet.read(sim, mix={"mix": 8})        # as if its vehicles were still to come
        assert fleet.share == pytest.approx({"a": 0.75, "b": 0.25})
        rng = np.random.default_rng(0)
        assert fleet.member("mix", 6.2, 2.0, "delivery", rng) == "b"
    finally:
        sim.close()


def test_before_any_vehicle_departs_the_mix_is_the_route_files(cross_net, tmp_path):
    """No vehicle present yet: the mix is what the route files depart (flows by their number,
    period, rate), a distribution's by its probabilities; bicycles do not count."""
    fleet = _fleet_of(cross_net, tmp_path,
        '<routes><vType id="car" length="4.3"/><vType id="lorry" vClass="truck" length="9"/>'
        '<vType id="bike" vClass="bicycle"/>'
        '<vTypeDistribution id="mix" vTypes="car lorry" probabilities="1 1"/>'
        '<flow id="a" type="car" begin="50" end="150" period="4" from="wc" to="ce"/>'
        '<flow id="b" type="mix" begin="50" end="3650" vehsPerHour="50" from="wc" to="ce"/>'
        '<flow id="c" type="bike" begin="50" end="150" period="1" from="wc" to="ce"/></routes>')
    assert fleet.share == pytest.approx({"car": 50 / 75, "lorry": 25 / 75})


def test_a_demand_rewritten_in_the_same_process_is_read_again(cross_net, tmp_path):
    """The demand's types are read once per version of its files (a run's requests and each scene's
    seeder ask again): a route file written anew is read anew, its distributions too."""
    types = '<vType id="car" length="4.3"/><vType id="lorry" vClass="truck" length="9"/>'
    flow = '<flow id="a" type="{}" begin="50" end="150" period="4" from="wc" to="ce"/>'
    assert set(_fleet_of(cross_net, tmp_path, f'<routes>{types}{flow.format("car")}</routes>').share) == {"car"}
    assert set(_fleet_of(cross_net, tmp_path, f'<routes>{types}{flow.format("lorry")}</routes>').share) == {"lorry"}
    mixed = f'<routes>{types}<vTypeDistribution id="mix" vTypes="car lorry" probabilities="3 1"/>{flow.format("mix")}</routes>'
    assert _fleet_of(cross_net, tmp_path, mixed).share == pytest.approx({"car": 0.75, "lorry": 0.25})
    assert _fleet_of(cross_net, tmp_path, mixed.replace('"3 1"', '"1 1"')).share == pytest.approx({"car": 0.5, "lorry": 0.5})


def test_a_vehicle_with_its_own_copy_of_a_type_counts_as_that_type(cross_net, tmp_path):
    """A host vehicle whose type parameters were set on it (SUMO's singular type ``car@v``, e.g. the
    user's TraCI) is one of the demand's cars in the mix, not a type of its own that leaves with it."""
    def own_copies(sim):
        for _ in range(10):
            sim.simulationStep()
        for v in sim.vehicle.getIDList():
            sim.vehicle.setMaxSpeed(v, 10.0)   # a parameter of the type, set on each vehicle
        assert all("@" in sim.vehicle.getTypeID(v) for v in sim.vehicle.getIDList())
    fleet = _fleet_of(cross_net, tmp_path,
        '<routes><vType id="car" length="4.3"/><vType id="lorry" vClass="truck" length="9"/>'
        '<flow id="a" type="car" begin="0" end="100" period="2" from="wc" to="ce"/>'
        '<flow id="b" type="lorry" begin="0" end="100" period="2" from="sc" to="cn"/></routes>', own_copies)
    assert set(fleet.share) == {"car", "lorry"}


@pytest.mark.slow
def test_run_seeds_the_scenarios_vtypes_and_names_an_unknown_one(scenario, tmp_path, capsys):
    from sumo_scendiff import run as run_cli
    net_path, add, rou = scenario
    tok = tmp_path / "tok.toml"
    tok.write_text('[[agents]]\nx = 30.0\ny = 1.6\nheading = 3.1416\nspeed = 5.0\nvtype = "coach"\n')   # on cw: no demand
    common = ["-n", net_path, "-a", add, "-r", rou, "--center", "0,0", "--scenes", "1", "--rollout", "0",
              "--steps", "8", "--begin", "40", "--vehicles", "12"]
    code = run_cli.main(run_cli.get_options(common + ["--tokens", str(tok), "-o", str(tmp_path / "out")]))
    assert code == 0, capsys.readouterr().err
    doc = json.load(open(tmp_path / "out" / "scene_000" / "scene.json"))
    seeded = [a for a in doc["agents"] if a["vehicle"]]
    assert seeded and all(a["vtype"] in OWN and a["sumo_type"] for a in seeded)
    assert all((a["length"], a["width"]) == pytest.approx(OWN[a["vtype"]][1:3]) for a in seeded)
    assert any(a["vtype"] == "coach" and a["token"] == 0 for a in seeded)
    tok.write_text('[[agents]]\nx = -30.0\ny = -1.6\nvtype = "bus_articulated"\n')
    try:
        code = run_cli.main(run_cli.get_options(common + ["--tokens", str(tok), "-o", str(tmp_path / "bad")]))
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and str(tok) in err and "bus_articulated" in err


@pytest.mark.slow
@pytest.mark.parametrize("amount", [["--demand-estimate"], ["--density", "25"]])
def test_fill_seeds_the_scenarios_vtypes(tmp_path, amount):
    """fill -r: every seeded vehicle, the demand's own (placed by the demand's estimate) or those the
    model draws (at a density asked for), is one of the demand's vTypes (fill.json names it), in the
    saved state as well."""
    import os

    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.fill.__main__ import get_options, main
    net = os.path.join(os.path.dirname(__file__), "..", "networks", "grid3x3_1lane.net.xml")
    edges = sorted(e.getID() for e in Network.load(net).sumo_net.getEdges())
    (tmp_path / "d.rou.xml").write_text(
        TYPES.replace("<additional>", "<routes>").replace("</additional>", "")
        + f'<flow id="cars" type="car" begin="0" end="600" period="4" from="{edges[0]}" to="{edges[-1]}"/>'
        + f'<flow id="coaches" type="coach" begin="0" end="600" period="12" from="{edges[1]}" to="{edges[-2]}"/>'
        + "</routes>")
    out = tmp_path / "o"
    assert main(get_options(["-n", net, "-r", str(tmp_path / "d.rou.xml"), "--begin", "120", "-o", str(out), *amount])) == 0
    doc = json.load(open(out / "fill.json"))
    seeded = [a for a in doc["agents"] if a["vehicle"]]
    assert seeded and all(a["vtype"] in OWN for a in seeded)
    assert all((a["length"], a["width"]) == pytest.approx(OWN[a["vtype"]][1:3]) for a in seeded)
    assert all(a.get("demand") for a in seeded) == ("--density" not in amount)
    libsumo.start([sumo_binary(), "-c", str(out / "scenario.sumocfg"), "--no-step-log", "true"])
    try:
        present = set(libsumo.vehicle.getIDList())
        got = {(libsumo.vehicle.getVehicleClass(a["vehicle"]), libsumo.vehicle.getLength(a["vehicle"]))
               for a in seeded if a["vehicle"] in present}
    finally:
        libsumo.close()
    assert got and got <= {("passenger", 4.3), ("bus", 12.0)}


@pytest.mark.slow
def test_the_model_fleet_on_request(scenario, tmp_path):
    """run and fill --model-fleet: with a demand, the vehicles the model draws keep its sizes on
    SUMO's default vType, none is one of the scenario's (the records say which fleet)."""
    import os

    from sumo_scendiff import run as run_cli
    from sumo_scendiff.fill.__main__ import get_options, main
    net_path, add, rou = scenario
    code = run_cli.main(run_cli.get_options(
        ["-n", net_path, "-a", add, "-r", rou, "--center", "0,0", "--scenes", "1", "--rollout", "0", "--steps", "8",
         "--begin", "40", "--vehicles", "12", "--model-fleet", "-o", str(tmp_path / "r")]))
    assert code == 0
    seeded = [a for a in json.load(open(tmp_path / "r" / "scene_000" / "scene.json"))["agents"] if a["vehicle"]]
    assert seeded and not any(a.get("vtype") for a in seeded)
    assert json.load(open(tmp_path / "r" / "run.json"))["fleet"] == "model"
    net = os.path.join(os.path.dirname(__file__), "..", "networks", "grid3x3_1lane.net.xml")
    edges = sorted(e.getID() for e in Network.load(net).sumo_net.getEdges())
    (tmp_path / "d.rou.xml").write_text(
        TYPES.replace("<additional>", "<routes>").replace("</additional>", "")
        + f'<flow id="coaches" type="coach" begin="0" end="600" period="6" from="{edges[1]}" to="{edges[-2]}"/>'
        + "</routes>")
    out = tmp_path / "f"
    assert main(get_options(["-n", net, "-r", str(tmp_path / "d.rou.xml"), "--begin", "120", "--density", "25",
                             "--model-fleet", "-o", str(out)])) == 0
    doc = json.load(open(out / "fill.json"))
    seeded = [a for a in doc["agents"] if a["vehicle"]]
    assert doc["fleet"] == "model" and seeded and not any(a.get("vtype") for a in seeded)


def test_a_vehicle_faster_than_its_vtype_departs_at_the_types_max_speed(scenario, cross_scene, tmp_path):
    """SUMO refuses a departure above the vType's maxSpeed: the agent drawn at 8 m/s given one of the
    scenario's types, which drive at most 3 m/s, departs at 3 m/s (recorded as slowed), not refused."""
    net_path, _, rou = scenario
    slow = tmp_path / "slow.add.xml"
    slow.write_text(TYPES.replace(' minGap=', ' maxSpeed="3" minGap='))
    got, scene, report, _ = _seed((net_path, str(slow), rou), cross_scene, seed=0)
    assert 2 in report.ids and 2 not in report.refused
    assert report.slowed[2] == (8.0, 3.0)
