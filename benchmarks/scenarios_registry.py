"""The corpus's registry (benchmarks/scenarios.py): every scenario by name, where it comes from, its licence
and what it exercises; the feature variants (``scenarios_features.py``) are rows of the same list."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from scenarios_city import MOST_REPO, most_files
from scenarios_features import all_features
from scenarios_osm import osm_scenarios


@dataclasses.dataclass(frozen=True)
class Scenario:
    name: str
    source: str            # where it comes from, for the table
    licence: str
    get: dict              # how to obtain it: kind (sumo-wheel / pypi / github) and its fields
    config: str            # the .sumocfg, relative to the scenario folder
    covers: tuple = ()     # what it exercises: left-hand, bicycles, trams, buses, pedestrians, ...
    begin: float | None = None   # T; None: the configuration's begin + offset
    offset: float = 120.0
    area: tuple | None = None
    timeout: dict = dataclasses.field(default_factory=dict)   # step -> s, over TIMEOUT
    note: str = ""
    clock: bool = False    # the product's --begin written as SUMO's clock (H:MM:SS), not in seconds


def _game(name, cfg, covers=(), **kw):
    return Scenario(name, "SUMO tools/game (eclipse-sumo wheel)", "EPL-2.0",
                    {"kind": "sumo-wheel", "path": f"tools/game/{cfg}"}, Path(cfg).name, covers, **kw)


def _sumolib_rilsa(name, folder, covers=(), **kw):
    """One of sumolib's RiLSA real-world examples (tools/sumolib/scenario/scenarios/RealWorld, EPL-2.0): a
    configuration whose root is ``<c>`` and names its network by SUMO's synonym ``net``; the flows by the
    example's own makeRoutes.py."""
    path = f"tools/sumolib/scenario/scenarios/RealWorld/{folder}/run.sumo.cfg"
    return Scenario(name, "SUMO tools/sumolib scenarios (eclipse-sumo wheel)", "EPL-2.0",
                    {"kind": "sumo-wheel", "path": path, "files": ["makeRoutes.py"], "steps": [["makeRoutes.py"]]},
                    "run.sumo.cfg", covers, **kw)


def _pypi(name, package, version, cfg, licence, covers=(), source=None, **kw):
    """``cfg``: the configuration's path inside the package's wheel."""
    return Scenario(name, source or f"{package} (PyPI)", licence,
                    {"kind": "pypi", "package": package, "version": version, "path": cfg}, Path(cfg).name,
                    covers, **kw)


def _sumo_rl(name, cfg, covers=(), source="sumo-rl (PyPI)", **kw):
    return _pypi(name, "sumo-rl", "1.4.5", f"sumo_rl/nets/{cfg}", "MIT", covers, source, **kw)


def _github(name, repo, files, cfg, licence, covers=(), steps=(), **kw):
    """``files``: the scenario folder's path -> (path in the repository, commit); ``steps``: the
    commands its authors give to build the rest (a SUMO binary or a SUMO tool's script, then its
    arguments), run in the folder in order."""
    return Scenario(name, f"github:{repo}", licence,
                    {"kind": "github", "repo": repo, "files": {k: list(v) for k, v in files.items()},
                     "steps": [list(c) for c in steps]}, cfg, covers, **kw)


SUMO_REPO = "eclipse-sumo/sumo"
MANHATTAN = "tests/complex/tutorial/manhattan/data/"
TUTORIAL = "tests/complex/tutorial/"


def _tutorial(folder: str, files: list) -> dict:
    """A tutorial's files (name, commit) as ``_github`` takes them: each at the commit the code index holds
    it at (the tutorials' files were last changed at different commits)."""
    return {f: (TUTORIAL + folder + f, c) for f, c in files}


PEDCROSSING = _tutorial("traci_pedestrian_crossing/data/", [
    ("pedcrossing.netccfg", "61b58fbf780d2cc31e15438dd590a5270c4da0c9"),
    ("pedcrossing.nod.xml", "ebef3bdbdf7d42f7a917365ac173d6f246b628e7"),
    ("pedcrossing.edg.xml", "61b58fbf780d2cc31e15438dd590a5270c4da0c9"),
    ("pedcrossing.con.xml", "61b58fbf780d2cc31e15438dd590a5270c4da0c9"),
    ("pedcrossing.tll.xml", "eb22e6fce8c11320876996dc4f363f0cfd5b773b"),
    ("pedcrossing.rou.xml", "ebef3bdbdf7d42f7a917365ac173d6f246b628e7"),
    ("run.sumocfg", "6b9178fc9d7b59efd33ab6f9dc98ea86bf1a57f8"),
    ("viewsettings.xml", "61b58fbf780d2cc31e15438dd590a5270c4da0c9")])   # sumo, too, wants its gui-settings-file
CIRCLES = _tutorial("circles/data/", [
    ("circles.sumocfg", "61b58fbf780d2cc31e15438dd590a5270c4da0c9"),
    ("circles.net.xml", "3eeb82c0a9f6c82e3137626a807f11e4eca2837a"),
    ("circles.rou.xml", "61b58fbf780d2cc31e15438dd590a5270c4da0c9"),
    ("circles.add.xml", "61b58fbf780d2cc31e15438dd590a5270c4da0c9")])
PUBLIC_TRANSPORT = _tutorial("public_transport/data/", [
    ("run.sumocfg", "81cf4240216734bc309054a668a97d70c25ba923"),
    ("net.net.xml", "81cf4240216734bc309054a668a97d70c25ba923"),
    ("pt.rou.xml", "deab49b2f227161684af2ebeece90ef1081d8292"),
    ("persons.rou.xml", "deab49b2f227161684af2ebeece90ef1081d8292"),
    ("stops.add.xml", "ec7f6e56e227fd342ce38a8dfd9f79e4328960c3")])
OUTPUT_PARSING = _tutorial("output_parsing/data/", [
    ("output_file.sumocfg", "9acde516efaa1e70d9292ea356e52678f1fe3f79"),
    ("circular.netccfg", "5629ad53b59bd84a98083b544c472c050eb1aeb8"),
    ("circular.nod.xml", "eb22e6fce8c11320876996dc4f363f0cfd5b773b"),
    ("circular.edg.xml", "eb22e6fce8c11320876996dc4f363f0cfd5b773b"),
    ("circular.typ.xml", "eb22e6fce8c11320876996dc4f363f0cfd5b773b"),
    ("circular.rou.xml", "5d6cd00a5b891ba5efeb98da52c4b9411aa6000c"),
    ("circular.add.xml", "61b58fbf780d2cc31e15438dd590a5270c4da0c9")])
# the network as shipped beside the tutorial (its plain files, at the commits the index holds, no longer agree
# on the junction's id); the routes by the tutorial's own generateRoutes.py (seeded)
TRACI_TLS = _tutorial("traci_tls/", [
    ("data/cross.sumocfg", "684df0808bd33fe16adcd6201571d7727b768d6e"),
    ("data/cross.net.xml", "387b777a8d365505feaeb206898386a5714b15de"),
    ("data/cross.det.xml", "d187f75d88e4098fdd0426690d5fdfb878992b20"),
    ("generateRoutes.py", "434fdf0cecdd2acd8c09278662d1b8ba852c249f")])
# MA2C's "real_net" (Chu et al.): a part of Monaco's MoST network with its induction loops; the demand is what
# its environment writes at reset (real_net_env.py: build_file.gen_rou_file with config_ma2c_real.ini's
# flow_rate 325 and seed 42, sim thread 0)
MA2C = "c3cadbd088a3f6946ecba667fd07cbd689947d32"
MA2C_FILES = {f: (f, MA2C) for f in ["real_net/data/build_file.py", "real_net/data/in/most.net.xml",
                                     "real_net/data/in/most.add.xml"]}
MA2C_ROUTES = ("import sys; sys.path.insert(0, 'real_net/data'); from build_file import gen_rou_file; "
               "gen_rou_file('real_net/data/', 325, seed=42, thread=0)")
# its "large_grid": the 5x5 grid its build_file.py writes (plain files, netconvert), the demand as its environment
# writes it at reset (config_ma2c_large.ini: peak flows 1100 and 925 veh/h, no initial density)
MA2C_GRID_ROUTES = ("from build_file import gen_rou_file; gen_rou_file('./', 1100, 925, 0, seed=12, thread=0)")
# Vidali's deep Q-learning signal control: one four-arm intersection; the demand by its own generator with its
# testing settings (settings/testing_settings.yaml: episode seed 10000, 1000 cars over 5400 s, turn chance 0.25)
TLCS = "482e4857504e80ffc8011a42cb44ebb8563877b5"
TLCS_FILES = {f: (f, TLCS) for f in ["intersection/sumo_config.sumocfg", "intersection/environment.net.xml",
                                     "src/tlcs/__init__.py", "src/tlcs/constants.py", "src/tlcs/generator.py"]}
TLCS_ROUTES = ("import sys; sys.path.insert(0, 'src'); from tlcs.generator import generate_routefile; "
               "generate_routefile(seed=10000, n_cars_generated=1000, max_steps=5400, turn_chance=0.25)")
# LibSignal's SUMO versions of CityFlow's real-world datasets (Hangzhou's Gudang district, Atlanta's Peachtree
# corridor), as its repository ships them
LIBSIGNAL = "127af9f93902778e556de2eedb2b606c4c9447e6"


def _libsignal(name: str, stem: str) -> dict:
    return {f"{stem}.{ext}": (f"data/raw_data/{name}/{stem}.{ext}", LIBSIGNAL)
            for ext in ("sumocfg", "net.xml", "rou.xml")}


# co-simulation frameworks' own SUMO scenarios, as their repositories ship them: Veins (its Erlangen example, a
# configuration named .sumo.cfg beside OSM polygons; its TraCI test net with a traffic-light file and unknown
# route attributes) and Eclipse MOSAIC (Hamburg's Sievekingplatz, its SUMO federate's test scenarios)
VEINS = "6571085f9879003d03e804f8cee074843a9a3953"
VEINS_TRACI = "subprojects/veins_testsims/sim/veins_testsims/traci/"
MOSAIC = "0328cfb7d03382a4cf316871679066a983028b93"
MOSAIC_FED = "fed/mosaic-sumo/src/test/resources/"


def _at(commit: str, folder: str, names: list) -> dict:
    """Files of one repository folder, each at ``commit``, as ``_github`` takes them."""
    return {n: (folder + n, commit) for n in names}


# OpenCDA's (a CARLA co-simulation framework's) freeway: a network netconvert made from OpenDRIVE with CARLA's
# type map, its demand redefining SUMO's DEFAULT_VEHTYPE and departing 320 m before an edge's end
OPENCDA_FREEWAY = "opencda/assets/2lane_freeway_simplified/2lane_freeway_simplified."


# users' own scenarios from SUMO's osmWebWizard, as they pushed them: Chiang Mai (left-hand traffic, motorcycles)
# and Chicago's Kennedy Expressway (its configuration names a file by a Windows path on its author's machine)
CHIANGMAI = "78bf6dd0dcc58b1ad32dd030bb30bc90cc801c1f"
KENNEDY = "18f6af397c80672141c0ba1c77b9672e52d44f78"


# tests of SUMO's own suite (tests/sumo): each test's files and the options.sumo files its runner joins (from
# tests/sumo down to the test's folder, outermost first), written as test.sumocfg by SUMO itself
# (scenarios_build._test_config); a file the code index holds once for several tests (it keeps one copy of
# identical files) is taken from where it is held
SUMO_TESTS = "tests/sumo/"
TEST_OPTIONS = ("tests/sumo/options.sumo", "43dfea9b48cb87f76cd1219f53cd1532a150af6d")
TAXI_TEST = SUMO_TESTS + "devices/taxi/2taxis_10persons/"
CONTAINER_TEST = SUMO_TESTS + "devices/taxi/containers/10containers_sameEdge"
SUBLANE_MIXED = SUMO_TESTS + "sublane_model/1edge_3lanes_mixed/"
SUBLANE_LEFTHAND = SUMO_TESTS + "sublane_model/basic/overtaking_lefthand/"
BATTERY_TEST = SUMO_TESTS + "devices/battery/chargingStations_totalPower2/"
NEMA_TEST = SUMO_TESTS + "tls/NEMA/basic/"


def _sumo_test(name: str, files: dict, options: list, covers: tuple, steps=(), **kw) -> Scenario:
    """A test of SUMO's suite: ``files`` as ``_github`` takes them, ``options`` its options.sumo files
    (path, commit) below tests/sumo's own, outermost first."""
    opts = {f"options/{i}.sumo": o for i, o in enumerate([TEST_OPTIONS, *options])}
    return _github(name, SUMO_REPO, {**files, **opts}, "test.sumocfg", "EPL-2.0", covers,
                   steps=[*steps, ["sumo-test-config", "test.sumocfg", *opts]], **kw)


SUMO_EXPERIMENTS = ("sumo-experiments", "5.8.4")
BOLOGNA = "sumo_experiments/preset_networks/bologna/acosta/"
BOLOGNA_COVERS = ("city", "lights", "buses", "bus lanes", "stops", "detectors", "vTypes in additional files")


REGISTRY: list[Scenario] = [
    _game("game_cross", "cross.sumocfg", ("lights", "TLS program file"), offset=60),
    _game("game_square", "square.sumocfg", ("right of way",), offset=60),
    _game("game_ramp", "ramp.sumocfg", ("highway", "on-ramp"), offset=60),
    _game("game_corridor", "corridor.sumocfg", ("arterial", "lights"), offset=60),
    _game("game_grid6", "grid6.sumocfg", ("grid", "lights"), offset=60),
    _game("game_fkk_in", "fkk_in.sumocfg", ("city", "lights"), offset=60),
    _game("game_bs3d", "bs3d.sumocfg", ("city", "pedestrians"), offset=60),
    _game("game_A10KW", "A10KW.sumocfg", ("highway", "trucks"), offset=300),
    _game("game_rail", "rail.sumocfg", ("rail", "stops", "rerouters"), offset=120),
    _game("game_DRT", "DRT.sumocfg", ("buses", "taxis", "persons", "stops"), offset=120),
    _game("game_DRT2", "DRT2.sumocfg", ("buses", "taxis", "persons", "stops"), offset=120),
    _game("game_fokr_bs", "fokr_bs_demo.sumocfg", ("bicycles", "pedestrians", "trips"), offset=60),
    _game("game_rail_demo", "rail_demo.sumocfg", ("rail",), offset=120),
    _sumolib_rilsa("sumolib_rilsa1", "RiLSA_example1",
                   ("lights", "trucks", "<c> configuration root", "option synonym net", "departPos base"),
                   offset=300),
    _sumo_rl("sumorl_single_intersection", "single-intersection/single-intersection.sumocfg",
             ("lights",)),
    _sumo_rl("sumorl_2way_single", "2way-single-intersection/single-intersection.sumocfg", ("lights",)),
    _sumo_rl("sumorl_3x3grid", "3x3grid/3x3grid.sumocfg", ("grid",)),
    _sumo_rl("sumorl_4x4_lucas", "4x4-Lucas/4x4.sumocfg", ("grid", "lights")),
    _sumo_rl("sumorl_4x4loop", "4x4loop/4x4loop.sumocfg", ("grid", "loop")),
    _sumo_rl("sumorl_nguyen", "Nguyen/nguyen.sumocfg", ("flows", "TAZ")),
    _sumo_rl("sumorl_ow", "OW/OW-traci.sumocfg", ("arterial", "TraCI port"),
             timeout={"sumo": 60, "run": 120, "fill": 120},
             note="its configuration sets remote-port: stock sumo waits for a TraCI client"),
    _sumo_rl("sumorl_simple", "simple/simple.sumocfg", ()),
    _sumo_rl("resco_arterial4x4", "RESCO/arterial4x4/arterial4x4.sumocfg", ("arterial", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_grid4x4", "RESCO/grid4x4/grid4x4.sumocfg", ("grid", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_cologne1", "RESCO/cologne1/cologne1.sumocfg", ("city", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_cologne3", "RESCO/cologne3/cologne3.sumocfg", ("city", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_cologne8", "RESCO/cologne8/cologne8.sumocfg", ("city", "lights"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_ingolstadt1", "RESCO/ingolstadt1/ingolstadt1.sumocfg", ("city", "lights", "buses"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_ingolstadt7", "RESCO/ingolstadt7/ingolstadt7.sumocfg", ("city", "lights", "buses"),
             source="RESCO via sumo-rl (PyPI)"),
    _sumo_rl("resco_ingolstadt21", "RESCO/ingolstadt21/ingolstadt21.sumocfg", ("city", "lights", "buses"),
             source="RESCO via sumo-rl (PyPI)"),
    _github("tutorial_manhattan", SUMO_REPO,
            {"manhattan.netgcfg": (MANHATTAN + "manhattan.netgcfg", "5629ad53b59bd84a98083b544c472c050eb1aeb8"),
             "manhattan.jtrrcfg": (MANHATTAN + "manhattan.jtrrcfg", "5629ad53b59bd84a98083b544c472c050eb1aeb8"),
             "manhattan.sumocfg": (MANHATTAN + "manhattan.sumocfg", "6b9178fc9d7b59efd33ab6f9dc98ea86bf1a57f8")},
            "manhattan.sumocfg", "EPL-2.0", ("grid", "jtrrouter flows"),
            steps=[["netgenerate", "-c", "manhattan.netgcfg", "-o", "net.net.xml"],
                   ["randomTrips.py", "--flows", "100", "-b", "0", "-e", "1", "-n", "net.net.xml", "-o",
                    "flows.xml", "--jtrrouter", "--trip-attributes", 'departPos="random" departSpeed="max"',
                    "--seed", "42"],
                   ["jtrrouter", "-c", "manhattan.jtrrcfg"]], offset=300),
    Scenario("lust_osm_wizard", "github:lcodeca/LuSTScenario, built by SUMO's osmWebWizard", "MIT (OSM: ODbL)",
             {"kind": "osm-wizard", "repo": "lcodeca/LuSTScenario",
              "commit": "5edb7ecb9ad196c39172b6eb95d19ed789f4b1a6", "path": "misc/lust.legacy.scenario.osm"},
             "osm.sumocfg", ("city", "roundabouts", "actuated lights", "bicycles", "pedestrians", "OSM"),
             offset=300),
    Scenario("gen_lefthand_grid", "built by SUMO's netgenerate + randomTrips", "EPL-2.0",
             {"kind": "generate", "netgenerate": ["--grid", "--grid.number", "4", "--grid.length", "150",
                                                  "--default.lanenumber", "2", "--lefthand", "--tls.guess",
                                                  "--sidewalks.guess", "--crossings.guess"],
              "trips": {"passenger": ["--period", "2"], "bicycle": ["--period", "8"],
                        "pedestrian": ["--period", "6", "--pedestrians"]}},
             "scenario.sumocfg", ("left-hand", "lights", "bicycles", "pedestrians")),
    Scenario("gen_lefthand_spider", "built by SUMO's netgenerate + randomTrips", "EPL-2.0",
             {"kind": "generate", "netgenerate": ["--spider", "--spider.arm-number", "6",
                                                  "--spider.circle-number", "4", "--spider.space-radius", "80",
                                                  "--lefthand", "--default.junctions.radius", "6"],
              "trips": {"passenger": ["--period", "1.5"], "truck": ["--period", "10"],
                        "motorcycle": ["--period", "6"]}},
             "scenario.sumocfg", ("left-hand", "right of way", "trucks", "motorcycles")),
    # SUMO's tutorials (tests/complex/tutorial), built by the steps of each tutorial's runner.py
    _github("tutorial_pedcrossing", SUMO_REPO, {"data/" + k: v for k, v in PEDCROSSING.items()},
            "data/run.sumocfg", "EPL-2.0", ("pedestrians", "crossing", "TLS program file", "../ paths"),
            steps=[["netconvert", "-c", "data/pedcrossing.netccfg", "--output-file", "pedcrossing.net.xml"],
                   ["randomTrips.py", "--net-file", "pedcrossing.net.xml", "--output-trip-file",
                    "pedestrians.trip.xml", "--seed", "42", "--pedestrians", "--prefix", "ped",
                    "--min-distance", "1", "--trip-attributes", 'departPos="random" arrivalPos="random"',
                    "--binomial", "4", "--period", "35"]], offset=300),
    _github("tutorial_circles", SUMO_REPO, CIRCLES, "circles.sumocfg", "EPL-2.0",
            ("loop", "rerouters", "vehicles that never arrive"), offset=300),
    _github("tutorial_public_transport", SUMO_REPO, PUBLIC_TRANSPORT, "run.sumocfg", "EPL-2.0",
            ("buses", "trams", "stops", "persons", "repeated route", "intermodal trips"), offset=300),
    _github("tutorial_output_parsing", SUMO_REPO, OUTPUT_PARSING, "output_file.sumocfg", "EPL-2.0",
            ("loop", "routes in additional files", "rerouters", "no internal links", "trucks", "fcd-output"),
            steps=[["netconvert", "-c", "circular.netccfg"]], offset=300),
    _github("tutorial_traci_tls", SUMO_REPO, TRACI_TLS, "data/cross.sumocfg", "EPL-2.0",
            ("lights", "induction loop", "additional file without <additional> root", "old network version"),
            steps=[["generateRoutes.py"]], offset=300),
    _github("ma2c_real_net", "cts198859/deeprl_signal_control", MA2C_FILES, "real_net/data/most_0.sumocfg",
            "MIT (network from MoST: GPL-3.0)", ("city", "lights", "flows with via", "lane area detectors"),
            steps=[["python", "-c", MA2C_ROUTES]], offset=600),
    _github("tlcs_intersection", "AndreaVidali/Deep-QLearning-Agent-for-Traffic-Signal-Control", TLCS_FILES,
            "intersection/sumo_config.sumocfg", "MIT", ("lights", "turn lanes", "random departure lanes"),
            steps=[["python", "-c", TLCS_ROUTES]], offset=1800),
    _github("ma2c_large_grid", "cts198859/deeprl_signal_control",
            {"build_file.py": ("large_grid/data/build_file.py", MA2C)}, "exp_0.sumocfg", "MIT",
            ("grid", "lights", "two-lane avenues", "lane area detectors"),
            steps=[["build_file.py"], ["python", "-c", MA2C_GRID_ROUTES]], offset=600),
    _github("libsignal_hangzhou_4x4", "DaRL-LibSignal/LibSignal",
            _libsignal("hangzhou_4x4_gudang_18041610_1h", "hangzhou_4x4_gudang_18041610_1h"),
            "hangzhou_4x4_gudang_18041610_1h.sumocfg", "none stated", ("city", "lights", "CityFlow data"), offset=600),
    _github("libsignal_atlanta_1x5", "DaRL-LibSignal/LibSignal", _libsignal("atlanta_1x5", "atlanta_1x5"),
            "atlanta_1x5.sumocfg", "none stated", ("arterial", "lights", "CityFlow data"), offset=600),
    _pypi("se_bologna_acosta", *SUMO_EXPERIMENTS, BOLOGNA + "run.sumocfg", "LGPL-2.1-or-later", BOLOGNA_COVERS,
          offset=600),
    _pypi("se_bologna_acosta_2704", *SUMO_EXPERIMENTS, BOLOGNA + "run_2704.sumocfg", "LGPL-2.1-or-later",
          BOLOGNA_COVERS, offset=600),
    _pypi("se_champs_elysees", *SUMO_EXPERIMENTS,
          "sumo_experiments/preset_networks/champs_elysees/run_11112.sumocfg", "LGPL-2.1-or-later",
          ("city", "lights", "OSM", "flows", "detectors"), offset=600),
    _github("veins_erlangen", "sommer/veins",
            _at(VEINS, "examples/veins/", ["erlangen.sumo.cfg", "erlangen.net.xml", "erlangen.rou.xml",
                                           "erlangen.poly.xml"]),
            "erlangen.sumo.cfg", "GPL-2.0-or-later OR CC-BY-SA-4.0",
            ("city", "OSM", "polygons", "step length 0.1", "configuration named .sumo.cfg")),
    _github("veins_testsims_traci", "sommer/veins",
            _at(VEINS, VEINS_TRACI, ["sumo.sumo.cfg", "net.net.xml", "routes.rou.xml", "polys.poly.xml",
                                     "tls.tls.xml", "additional.xml"]),
            "sumo.sumo.cfg", "GPL-2.0-or-later OR CC-BY-SA-4.0",
            ("TLS program file", "polygons", "unknown route attributes", "departSpeed max"), offset=30),
    _github("mosaic_sievekingplatz", "eclipse/mosaic",
            _at(MOSAIC, "bundle/src/assembly/resources/scenarios/Sievekingplatz/sumo/",
                ["sievekingplatz.sumocfg", "sievekingplatz.net.xml", "sievekingplatz.rou.xml",
                 "sievekingplatz.bus.add.xml"]),
            "sievekingplatz.sumocfg", "EPL-2.0",
            ("city", "buses", "stops", "bicycles", "junction model parameters", "step length 0.1"), offset=20),
    _github("mosaic_density_flow", "eclipse/mosaic",
            _at(MOSAIC, MOSAIC_FED + "density-flow-scenario/",
                ["density_flow.sumocfg", "density_flow.net.xml", "density_flow.rou.xml",
                 "density_flow.detector.xml"]),
            "density_flow.sumocfg", "EPL-2.0", ("IDMM car-following", "departLane best", "speedDev", "detectors")),
    _github("mosaic_sumo_test", "eclipse/mosaic",
            _at(MOSAIC, MOSAIC_FED + "sumo-test-scenario/",
                ["scenario.sumocfg", "scenario.net.xml", "scenario.rou.xml", "scenario.detector.xml",
                 "parking.add.xml"]),
            "scenario.sumocfg", "EPL-2.0", ("buses", "lines", "stops", "parkingAreas", "speedFactor distribution"),
            offset=15),
    _github("mosaic_tiergarten_jump", "eclipse/mosaic",
            _at(MOSAIC, "test/scenarios/sumo-predefined-scenario-integration/sumo/",
                ["teleport_tiergarten.sumocfg", "tiergarten.net.xml", "teleport_tiergarten.rou.xml"]),
            "teleport_tiergarten.sumocfg", "EPL-2.0", ("city", "OSM", "stop with jump"), offset=15),
    # its network as the test's net.net.xml header says netgenerate built it (the index holds it at SUMO 1.4)
    _sumo_test("sumotest_taxi_2taxis_10persons",
               _at("11e14c76e0221f3bdab6440c5886816da4cc2a42", TAXI_TEST,
                   ["input_routes.rou.xml", "input_routes2.rou.xml"]),
               [(TAXI_TEST + "options.sumo", "519e7f1ba3c06a925161729bdb6e8f351ef74fba")],
               ("taxis", "persons", "rides", "triggered stops", "sidewalks"),
               steps=[["netgenerate", "--grid", "--grid.length", "300", "--grid.x-number", "6", "--grid.y-number",
                       "3", "--sidewalks.guess", "--walkingareas", "-o", "net.net.xml"]], offset=60),
    _sumo_test("sumotest_containers_bidi",
               {"net.net.xml": (CONTAINER_TEST + "_bidi/net.net.xml", "bcdbb70c15f6a85a91c5667369e2f3f9e153bc21"),
                "input_routes.rou.xml": (CONTAINER_TEST + "_bidi/input_routes.rou.xml",
                                         "65c567e7aa02b7bd6f23ae88b1a1b1b41642ae0f"),
                "input_additional.add.xml": (CONTAINER_TEST + "/input_additional.add.xml",
                                             "bcdbb70c15f6a85a91c5667369e2f3f9e153bc21")},
               [(CONTAINER_TEST + "_bidi/options.sumo", "c2b6a0b9e460e5c7128ae422e134d2ad33835494")],
               ("bidirectional edge", "containers", "containerFlow", "taxi device", "trucks"), offset=30),
    # SUMO's sublane model (lateral-resolution): a vTypeDistribution of cars and mopeds queueing at a red light
    # on three lanes, and a left-hand road where a car overtakes a slow one at step length 0.2
    _sumo_test("sumotest_sublane_mixed",
               {"net.net.xml": (SUBLANE_MIXED + "net.net.xml", "bfc373cc087c232989c310f972c6ac55354e9924"),
                "input_routes.rou.xml": (SUBLANE_MIXED + "input_routes.rou.xml",
                                         "9ae189ee1ee2531a4969e67393a426e66b388ca1")},
               [(SUBLANE_MIXED + "options.sumo", "519e7f1ba3c06a925161729bdb6e8f351ef74fba")],
               ("sublane model", "mopeds", "vTypeDistribution", "departPosLat random", "queue at a red light"),
               offset=90),
    _sumo_test("sumotest_sublane_lefthand",
               {"net.net.xml": (SUBLANE_LEFTHAND + "net.net.xml", "90d678d1082d240d69afc42f170b1c821bad12dd"),
                "input_routes.rou.xml": (SUBLANE_LEFTHAND + "input_routes.rou.xml",
                                         "519e7f1ba3c06a925161729bdb6e8f351ef74fba")},
               [(SUBLANE_LEFTHAND + "options.sumo", "90d678d1082d240d69afc42f170b1c821bad12dd")],
               ("left-hand", "sublane model", "overtaking", "step length 0.2", "no internal links"), offset=8),
    # a NEMA dual-ring actuated controller at a right-on-red junction of a 3D network in UTM coordinates
    # (30 km from its origin, not normalised), flows by probability, the controller's states saved by timedEvents
    _sumo_test("sumotest_nema",
               {**_at("40756f0cc149e3022da4f1bc6936c4c543a6665c", NEMA_TEST, ["net.net.xml"]),
                **_at("ec7f6e56e227fd342ce38a8dfd9f79e4328960c3", NEMA_TEST,
                      ["input_routes.rou.xml", "input_additional2.add.xml"]),
                **_at("00728c34c28fe2940303276986130d62d398d22c", NEMA_TEST, ["input_additional.add.xml"])},
               [(NEMA_TEST + "options.sumo", "81cf4240216734bc309054a668a97d70c25ba923")],
               ("NEMA controller", "right on red", "3D network", "UTM coordinates", "timedEvent outputs"),
               offset=300),
    # a test with a configuration of its own (netedit's): battery devices by the configuration's probability,
    # trips stopping at a chargingStation of limited total power and at an edge
    _github("sumotest_battery_charging", SUMO_REPO,
            {**_at("5150e0a9e4747aa0247508c9bea6e524a0a242bf", BATTERY_TEST, ["sumo.sumocfg", "input_routes.rou.xml"]),
             **_at("a6f436312586af2d469c62fbcc20b42d98a91fb5", BATTERY_TEST,
                   ["net.net.xml", "input_additional.add.xml"])},
            "sumo.sumocfg", "EPL-2.0",
            ("battery device", "chargingStation", "stops at an edge", "trips with stops", "turnarounds"),
            offset=150),
    _github("opencda_2lane_freeway", "ucla-mobility/OpenCDA",
            {"2lane_freeway_simplified.sumocfg": (OPENCDA_FREEWAY + "sumocfg", "7dbb3159206c6dbffd08722d36b9c218caaf777f"),
             "2lane_freeway_simplified.net.xml": (OPENCDA_FREEWAY + "net.xml", "1db917fe8b8ec3626e1b3adf4dced1ef64bf83fd"),
             "2lane_freeway_simplified.rou.xml": (OPENCDA_FREEWAY + "rou.xml", "034b14711f563d03327e0d3ff8f6902744db10cb")},
            "2lane_freeway_simplified.sumocfg", "MIT",
            ("highway", "merge", "network from OpenDRIVE", "DEFAULT_VEHTYPE redefined", "negative departPos")),
    _github("osm_chiangmai", "greede14/OSM-SUMO-ChiangMai-Research",
            _at(CHIANGMAI, "", ["osm.sumocfg", "osm.net.xml.gz", "osm.motorcycle.trips.xml",
                                "osm.passenger.trips.xml", "osm.poly.xml.gz", "osm.view.xml"]),
            "osm.sumocfg", "none stated (OSM: ODbL)",
            ("city", "OSM", "left-hand", "motorcycles", "trips", "route errors ignored"), offset=300),
    _github("osm_kennedy_expressway", "aryan-SVG/traffic_simulation_Kennedy_Expressway",
            _at(KENNEDY, "", ["osm.sumocfg", "osm.net.xml.gz", "osm.passenger.trips.xml", "osm.view.xml"]),
            "osm.sumocfg", "none stated (OSM: ODbL)",
            ("highway", "OSM", "trips", "junction-taz", "a Windows path in route-files"), offset=300),
    # city-scale: Monaco's network built from the authors' OSM-like data and netconvert configuration, their
    # commercial, special, bus, train and highway demand (scenarios_city.py: what is built and left out)
    Scenario("most_monaco", "github:lcodeca/MoSTScenario (network built from its tools/data)", "GPL-3.0-or-later",
             {"kind": "github", "repo": MOST_REPO, "files": {k: list(v) for k, v in most_files().items()},
              "steps": [], "builder": "most"}, "most.sumocfg",
             ("city", "OSM", "parkingAreas", "buses", "trains", "stops", "rerouting devices", "sublane model",
              "step length 0.25", "route errors ignored", "persons' demand absent"), begin=21600.0,
             area=(4000.0, 1000.0, 5000.0, 2000.0),
             note="T 6:00, 2 h after the configuration's begin (stock SUMO takes about 9 min to 8:00 here); "
                  "the fill's area 1 km of central Monaco"),
    Scenario("most_monaco_dense", "github:lcodeca/MoSTScenario's network + SUMO randomTrips", "GPL-3.0-or-later",
             {"kind": "github", "repo": MOST_REPO, "files": {k: list(v) for k, v in most_files().items()},
              "steps": [], "builder": "most_dense"}, "dense.sumocfg",
             ("city", "OSM", "heavy demand", "48 MB route file", "jams"), offset=120.0,
             area=(4000.0, 1000.0, 5000.0, 2000.0),
             note="randomTrips at 25 veh/s on Monaco: about 3,000 vehicles on the road at T"),
]

def _feature(name: str) -> Scenario:
    """A feature variant: the generated grid with one SUMO feature (scenarios_features.FEATURES)."""
    _, covers, kw = all_features()[name]
    return Scenario(name, "feature variant: netgenerate grid + randomTrips", "generated",
                    {"kind": "feature", "feature": name}, **{"config": "scenario.sumocfg", "covers": covers, **kw})


REGISTRY += osm_scenarios(Scenario)
REGISTRY += [_feature(name) for name in all_features()]

