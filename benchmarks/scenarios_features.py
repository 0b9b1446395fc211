"""The corpus's feature matrix (benchmarks/scenarios.py, source kind ``feature``): a small generated scenario
(SUMO's netgenerate grid with traffic lights, randomTrips demand, 300 m a side) plus one SUMO feature that
real-world scenarios use, one row each, so that a held-out scenario using it does not break the product.

Each builder writes its folder (network, demand, additional files, configuration) and returns what it ran;
every variant runs in stock SUMO first (the corpus's first step), else the variant is wrong, not a finding.
The syntax is SUMO's documented one (sumo.dlr.de: Simulation/Meso, Simulation/SublaneModel, Specification/
Persons, Simulation/ParkingArea, Definition_of_Vehicles..., Simulation/Calibrator, Models/Electric, ...).
"""
from __future__ import annotations

import gzip
import shutil
import subprocess
import sys
from pathlib import Path

END = 300                  # s: the demand's last departure (T is 120 s, the corpus rolls 30 s past it)
GRID = ["--grid", "--grid.number", "4", "--grid.length", "100", "--tls.guess"]   # junctions A0 .. D3


def _sumo_home() -> Path:
    import sumo
    return Path(sumo.SUMO_HOME)


def _binary(name: str) -> str:
    return shutil.which(name) or str(_sumo_home() / "bin" / name)


def netgenerate(dest: Path, out: str, *extra: str) -> None:
    subprocess.run([_binary("netgenerate"), *GRID, *extra, "-o", out, "--seed", "42"], cwd=dest, check=True,
                   capture_output=True, timeout=600)


def trips(dest: Path, net: str, vclass: str, out: str, *extra: str) -> str:
    """randomTrips' routes for one vClass (seeded); pedestrians by ``--pedestrians`` in ``extra``."""
    cls = ["--vehicle-class", vclass, "--vclass", vclass] if vclass != "pedestrian" else []
    subprocess.run([sys.executable, str(_sumo_home() / "tools" / "randomTrips.py"), "-n", net, "-e", str(END),
                    "--seed", "42", "--prefix", vclass[:3], "--validate", "-r", out,
                    "-o", out.replace(".rou.xml", ".trips.xml"), *cls, *extra],
                   cwd=dest, check=True, capture_output=True, timeout=600)
    return out


def sumocfg(path: Path, net: str, routes=(), additionals=(), begin="0", end=str(END), **options) -> None:
    """A configuration; ``options`` by SUMO's option names (``_`` for ``-``, ``__`` for ``.``)."""
    inputs = [("net-file", net)] + [("route-files", ",".join(routes))] * bool(routes) \
        + [("additional-files", ",".join(additionals))] * bool(additionals)
    opts = [("begin", begin), ("end", end)] + [(k.replace("__", ".").replace("_", "-"), str(v))
                                               for k, v in options.items()]
    body = "".join(f'        <{k} value="{v}"/>\n' for k, v in inputs)
    rest = "".join(f'        <{k} value="{v}"/>\n' for k, v in opts)
    path.write_text(f"<configuration>\n    <input>\n{body}    </input>\n    <processing>\n{rest}"
                    "    </processing>\n</configuration>\n")


def base(dest: Path, *net_extra: str, classes=("passenger",), period: float = 2.0, **options) -> None:
    """The grid, one randomTrips file per vClass and scenario.sumocfg with ``options``."""
    netgenerate(dest, "net.net.xml", *net_extra)
    routes = [trips(dest, "net.net.xml", c, f"{c}.rou.xml", "--period", f"{period * (3 if c != 'passenger' else 1)}")
              for c in classes]
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", routes, **options)


def write(dest: Path, name: str, root: str, body: str) -> str:
    (dest / name).write_text(f"<{root}>\n{body}</{root}>\n")
    return name


# --------------------------------------------------------------------------- the features

def meso(dest: Path) -> None:
    base(dest, mesosim="true")


def sublane(dest: Path) -> None:
    base(dest, "--default.lanenumber", "2", classes=("passenger", "bicycle"), lateral_resolution="0.8")


def step_fine(dest: Path) -> None:
    base(dest, step_length="0.1", default__action_step_length="0.5")


def step_coarse(dest: Path) -> None:
    base(dest, step_length="1.0", step_method__ballistic="true")


PERSONS = """    <vType id="bus" vClass="bus"/>
    <route id="line" edges="A1B1 B1C1 C1D1"/>
    <flow id="bus" type="bus" route="line" line="L1" begin="0" end="300" period="40">
        <stop busStop="bs_a" duration="10"/>
        <stop busStop="bs_b" duration="10"/>
    </flow>
    <personFlow id="walkers" begin="0" end="300" period="8">
        <walk from="A0B0" to="D3C3"/>
    </personFlow>
    <personFlow id="riders" begin="0" end="300" period="25">
        <walk from="A1A2" busStop="bs_a"/>
        <ride busStop="bs_b" lines="L1"/>
    </personFlow>
    <route id="trig" edges="B0C0 C0C1 C1C2"/>
    <vehicle id="car_triggered" depart="triggered" route="trig"/>
    <vehicle id="car_triggered2" depart="triggered" route="trig"/>
    <person id="driver" depart="100">
        <ride from="B0C0" to="C1C2" lines="car_triggered"/>
    </person>
    <person id="driver2" depart="110">
        <ride from="B0C0" to="C1C2" lines="car_triggered2"/>
    </person>
"""


BUS_STOPS = """    <busStop id="bs_a" lane="A1B1_1" startPos="20" endPos="50"/>
    <busStop id="bs_b" lane="C1D1_1" startPos="20" endPos="50"/>
"""


def persons(dest: Path) -> None:
    """personFlow walking, persons riding a bus line between busStops, vehicles departing ``triggered``
    (a person gets in), on a network with sidewalks (lane 0) and crossings."""
    base(dest, "--sidewalks.guess", "--crossings.guess")
    extra = write(dest, "persons.rou.xml", "routes", PERSONS)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", extra],
            [write(dest, "stops.add.xml", "additional", BUS_STOPS)])


PARKING = """    <parkingArea id="pa_1" lane="A1B1_0" startPos="5" endPos="60" roadsideCapacity="6"/>
    <parkingArea id="pa_2" lane="C2D2_0" startPos="5" endPos="60" roadsideCapacity="6"/>
"""
PARKERS = """    <route id="r_park" edges="A0A1 A1B1 B1C1 C1C2 C2D2 D2D3"/>
    <flow id="parker" route="r_park" begin="0" end="200" period="15" departSpeed="max">
        <stop parkingArea="pa_1" duration="150" parking="true"/>
        <stop parkingArea="pa_2" duration="20" parking="true"/>
    </flow>
    <flow id="waiter" route="r_park" begin="0" end="200" period="30">
        <stop lane="B1C1_0" endPos="60" until="140"/>
    </flow>
"""


def parking(dest: Path) -> None:
    """parkingAreas with vehicles parked (``parking="true"``, durations long enough that some are parked
    at T) and a stop with ``until``."""
    base(dest)
    add = write(dest, "parking.add.xml", "additional", PARKING)
    parkers = write(dest, "parkers.rou.xml", "routes", PARKERS)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", parkers], [add])


DISTRIBUTIONS = """    <vTypeDistribution id="mix">
        <vType id="small" length="4" maxSpeed="30" probability="0.7"/>
        <vType id="van" length="6.5" maxSpeed="25" accel="2" probability="0.3" vClass="delivery"/>
    </vTypeDistribution>
    <routeDistribution id="rd">
        <route id="rd_a" edges="A0B0 B0C0 C0D0" probability="2"/>
        <route id="rd_b" edges="A1B1 B1C1 C1D1" probability="1"/>
        <route id="rd_c" edges="D2C2 C2B2 B2A2" probability="1"/>
    </routeDistribution>
    <flow id="by_probability" type="mix" route="rd" begin="0" end="300" probability="0.15"/>
    <flow id="by_exp" type="mix" route="rd" begin="0" end="300" period="exp(0.2)"/>
    <flow id="by_number" type="mix" route="rd" begin="0" end="300" number="60"/>
"""


def distributions(dest: Path) -> None:
    base(dest)
    flows = write(dest, "flows.rou.xml", "routes", DISTRIBUTIONS)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", flows])


def _gzip(dest: Path, name: str) -> str:
    with open(dest / name, "rb") as f, gzip.open(dest / f"{name}.gz", "wb") as g:
        shutil.copyfileobj(f, g)
    (dest / name).unlink()
    return f"{name}.gz"


VTYPES = """    <vType id="commuter" vClass="passenger" length="4.8" maxSpeed="33" sigma="0.6"/>
    <vType id="hauler" vClass="truck" length="12" maxSpeed="22"/>
"""
TYPED = """    <flow id="commuters" type="commuter" from="A0B0" to="C3D3" begin="0" end="300" period="9"/>
    <flow id="haulers" type="hauler" from="D0C0" to="A3A2" begin="0" end="300" period="20"/>
"""


LOOPS = """    <inductionLoop id="loop" lane="B2C2_0" pos="40" period="60" file="loops.xml"/>
"""


def gzipped(dest: Path) -> None:
    """A gzip-compressed network and route file, several route files, the vTypes in their own file listed
    last (of the additional files: stock SUMO refuses a vType that a later route file defines)."""
    netgenerate(dest, "net.net.xml")
    cars = trips(dest, "net.net.xml", "passenger", "passenger.rou.xml", "--period", "2")
    routes = [_gzip(dest, cars), write(dest, "typed.rou.xml", "routes", TYPED)]
    adds = [write(dest, "loops.add.xml", "additional", LOOPS), write(dest, "vtypes.add.xml", "additional", VTYPES)]
    sumocfg(dest / "scenario.sumocfg", _gzip(dest, "net.net.xml"), routes, adds)


CONTROL = """    <route id="cal_route" edges="A2B2 B2C2 C2D2"/>
    <calibrator id="cal" edge="B2C2" pos="20" output="calibrator.xml">
        <flow begin="0" end="300" route="cal_route" vehsPerHour="600" speed="12"/>
    </calibrator>
    <variableSpeedSign id="vss" lanes="B1C1_0 C1B1_0">
        <step time="0" speed="6"/>
        <step time="100" speed="9"/>
        <step time="200" speed="13.89"/>
    </variableSpeedSign>
    <variableSpeedSign id="vss_by_file" lanes="C3B3_0" file="speeds/vss.xml"/>
    <rerouter id="closure" edges="B0B1 A1B1 C1B1">
        <interval begin="0" end="1000">
            <closingReroute id="B1B2"/>
        </interval>
    </rerouter>
"""


VSS_STEPS = """    <step time="0" speed="8"/>
    <step time="150" speed="13.89"/>
"""


def traffic_control(dest: Path) -> None:
    """A calibrator, variable speed signs (one with its steps in a file of their own) and a rerouter
    closing an edge."""
    base(dest)
    (dest / "speeds").mkdir()
    write(dest, "speeds/vss.xml", "vss", VSS_STEPS)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml"],
            [write(dest, "control.add.xml", "additional", CONTROL)])


def no_internal(dest: Path) -> None:
    base(dest, "--no-internal-links")


def opposites(dest: Path) -> None:
    """Overtaking on the opposite direction's lane (one lane each way, slow trucks among cars)."""
    base(dest, "--opposites.guess", classes=("passenger", "truck"))


ELECTRIC = """    <vType id="ev" vClass="evehicle" emissionClass="Energy/unknown" maxSpeed="30" mass="1830">
        <param key="has.battery.device" value="true"/>
        <param key="device.battery.capacity" value="2000"/>
        <param key="device.battery.chargeLevel" value="1500"/>
        <param key="frontSurfaceArea" value="2.6"/>
        <param key="airDragCoefficient" value="0.35"/>
        <param key="maximumPower" value="150000"/>
    </vType>
    <flow id="evs" type="ev" from="A0B0" to="D3C3" begin="0" end="300" period="10"/>
    <flow id="chargers" type="ev" from="A1B1" to="C3D3" begin="0" end="300" period="30">
        <stop chargingStation="cs" duration="40"/>
    </flow>
"""
CHARGING = """    <chargingStation id="cs" lane="B1C1_0" startPos="20" endPos="80" power="22000" efficiency="0.95"/>
"""


def electric(dest: Path) -> None:
    """Battery electric vehicles (battery device params) and a chargingStation they stop at."""
    base(dest)
    evs = write(dest, "electric.rou.xml", "routes", ELECTRIC)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", evs],
            [write(dest, "charging.add.xml", "additional", CHARGING)])


def options_insertion(dest: Path) -> None:
    base(dest, scale="2", time_to_teleport="-1", ignore_route_errors="true", max_depart_delay="5",
         collision__action="remove")


def options_models(dest: Path) -> None:
    """IDM for every vehicle, rerouting devices on all, the begin written as a clock (and the product's
    --begin too: the registry row's ``clock``)."""
    base(dest, carfollow__model="IDM", device__rerouting__probability="1")
    cfg = dest / "scenario.sumocfg"
    cfg.write_text(cfg.read_text().replace('<begin value="0"/>', '<begin value="0:00:00"/>'))


TAZ = """    <taz id="west" edges="A0A1 A1A2 A2A3 A1B1 A2B2"/>
    <taz id="east" edges="D0D1 D1D2 D2D3 C1D1 C2D2"/>
"""
TAZ_TRIPS = """    <flow id="by_junction" fromJunction="A0" toJunction="D3" begin="0" end="300" period="8"/>
    <flow id="by_junction_back" fromJunction="D2" toJunction="A1" begin="0" end="300" period="10"/>
    <flow id="by_taz" fromTaz="west" toTaz="east" begin="0" end="300" period="9"/>
"""


def taz(dest: Path) -> None:
    """Trips between junctions (``--junction-taz``) and between TAZ of a .taz.xml."""
    base(dest)
    flows = write(dest, "taz.rou.xml", "routes", TAZ_TRIPS)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", flows],
            [write(dest, "districts.taz.xml", "additional", TAZ)], junction_taz="true")


PATHS_HOME = "Szenario Straße ü"     # spaces and non-ASCII letters in the folder names


def paths(dest: Path) -> None:
    """The configuration in a folder with spaces and non-ASCII letters, the network in a sibling folder
    named as ``../net/x.net.xml``."""
    home = dest / PATHS_HOME
    (home / "net").mkdir(parents=True)
    (home / "cfg").mkdir()
    netgenerate(home / "net", "x.net.xml")
    trips(home / "cfg", "../net/x.net.xml", "passenger", "demand.rou.xml", "--period", "2")
    sumocfg(home / "cfg" / "scenario.sumocfg", "../net/x.net.xml", ["demand.rou.xml"])


TRAM_LANES = """    <edge id="A1B1" numLanes="2"><lane index="1" allow="tram"/></edge>
    <edge id="B1C1" numLanes="2"><lane index="1" allow="tram"/></edge>
    <edge id="C1D1" numLanes="2"><lane index="1" allow="tram"/></edge>
    <edge id="D1C1" numLanes="2"><lane index="1" allow="tram"/></edge>
    <edge id="C1B1" numLanes="2"><lane index="1" allow="tram"/></edge>
    <edge id="B1A1" numLanes="2"><lane index="1" allow="tram"/></edge>
"""
TRAM_LINE = """    <busStop id="tram_a" lane="A1B1_1" startPos="15" endPos="50" lines="T1"/>
    <busStop id="tram_b" lane="C1D1_1" startPos="15" endPos="50" lines="T1"/>
    <busStop id="tram_c" lane="D1C1_1" startPos="15" endPos="50" lines="T1"/>
    <busStop id="tram_d" lane="B1A1_1" startPos="15" endPos="50" lines="T1"/>
"""
TRAMS = """    <vType id="tram" vClass="tram" length="30"/>
    <route id="tram_e" edges="A1B1 B1C1 C1D1"/>
    <route id="tram_w" edges="D1C1 C1B1 B1A1"/>
    <flow id="tram_east" type="tram" route="tram_e" line="T1" begin="0" end="300" period="60">
        <stop busStop="tram_a" duration="15"/>
        <stop busStop="tram_b" duration="15"/>
    </flow>
    <flow id="tram_west" type="tram" route="tram_w" line="T1" begin="0" end="300" period="60">
        <stop busStop="tram_c" duration="15"/>
        <stop busStop="tram_d" duration="15"/>
    </flow>
"""


def tram(dest: Path) -> None:
    """A tram line (vClass tram, stops) on a tram-only lane beside the car lane of a street of the grid."""
    netgenerate(dest, "grid.net.xml")
    write(dest, "tram.edg.xml", "edges", TRAM_LANES)
    subprocess.run([_binary("netconvert"), "-s", "grid.net.xml", "-e", "tram.edg.xml", "-o", "net.net.xml"],
                   cwd=dest, check=True, capture_output=True, timeout=600)
    (dest / "grid.net.xml").unlink()
    cars = trips(dest, "net.net.xml", "passenger", "passenger.rou.xml", "--period", "2")
    stops = write(dest, "tram.add.xml", "additional", TRAM_LINE)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", [cars, write(dest, "tram.rou.xml", "routes", TRAMS)],
            [stops])


DEPARTURES = """    <flow id="best_lane" from="A0B0" to="D3C3" begin="0" end="300" period="9" departLane="best"
          departPos="random_free" departSpeed="desired" arrivalPos="random"/>
    <flow id="free_lane" from="D0C0" to="A3A2" via="C0C1 C1B1" begin="0" end="300" period="11" departLane="free"
          departPos="last" departSpeed="max" arrivalLane="current"/>
    <flow id="random_lane" from="B3B2" to="C0D0" begin="0" end="300" vehsPerHour="360" departLane="random"
          departSpeed="random" departPos="base" arrivalSpeed="0"/>
    <include href="included.rou.xml"/>
"""
INCLUDED = """    <vehicle id="late_one" depart="110" departSpeed="speedLimit">
        <route edges="A2B2 B2C2 C2D2"/>
    </vehicle>
"""


def departures(dest: Path) -> None:
    """Departure and arrival attributes as generated demand writes them (departLane best/free/random,
    departPos random_free/last, departSpeed desired/max/random/speedLimit, arrivalPos, via, vehsPerHour)
    and a route file that includes another."""
    base(dest)
    write(dest, "included.rou.xml", "routes", INCLUDED)
    flows = write(dest, "departures.rou.xml", "routes", DEPARTURES)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", flows])


# name -> (builder, what it covers, the row's fields over the corpus's defaults)
FEATURES = {
    "feat_meso": (meso, ("mesoscopic",), {}),
    "feat_sublane": (sublane, ("sublane model", "bicycles"), {}),
    "feat_step_fine": (step_fine, ("step length 0.1", "action step 0.5"), {}),
    "feat_step_coarse": (step_coarse, ("step length 1.0", "ballistic"), {}),
    "feat_persons": (persons, ("pedestrians", "persons", "buses", "stops", "triggered departure"), {}),
    "feat_parking": (parking, ("parkingAreas", "stops"), {}),
    "feat_distributions": (distributions, ("vTypeDistribution", "routeDistribution", "flows"), {}),
    "feat_gzip": (gzipped, ("gzip files", "several route files", "trucks"), {}),
    "feat_traffic_control": (traffic_control, ("calibrators", "variable speed signs", "rerouters"), {}),
    "feat_no_internal": (no_internal, ("no internal links",), {}),
    "feat_opposites": (opposites, ("opposite-direction overtaking", "trucks"), {}),
    "feat_electric": (electric, ("electric vehicles", "chargingStations"), {}),
    "feat_options_insertion": (options_insertion, ("scale", "no teleport", "route errors", "depart delay",
                                                   "collision remove"), {}),
    "feat_options_models": (options_models, ("IDM", "rerouting devices", "clock times"), {"clock": True}),
    "feat_taz": (taz, ("junction-taz", "TAZ"), {}),
    "feat_paths": (paths, ("paths with spaces and non-ASCII", "../ paths"),
                   {"config": f"{PATHS_HOME}/cfg/scenario.sumocfg"}),
    "feat_tram": (tram, ("trams", "stops"), {}),
    "feat_departures": (departures, ("departure attributes", "via", "included route file"), {}),
}


def all_features() -> dict:
    """The matrix: this module's rows and those of its second part (scenarios_features_more.py, built on
    this module's helpers), in that order."""
    from scenarios_features_more import MORE_FEATURES
    return {**FEATURES, **MORE_FEATURES}


def build_feature(name: str, dest: Path) -> dict:
    builder = all_features()[name][0]
    builder(dest)
    return {"built_with": f"benchmarks/{builder.__module__}.py:{builder.__name__}"}
