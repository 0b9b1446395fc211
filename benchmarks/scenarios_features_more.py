"""The feature matrix's second part (benchmarks/scenarios_features.py): features that SUMO's own tests and
public scenarios use and the first rows do not, each on the same generated grid (or, for a level crossing,
a network of plain files), in SUMO's documented syntax (sumo.dlr.de: Simulation/Basic_Definition,
Specification/Persons (personTrip), Simulation/Railways (rail crossings), Simulation/Emergency,
Simulation/Parallelization, Simulation/Lane-Changing (continuous lane change), Simulation/Output/SSM_Device)."""
from __future__ import annotations

import subprocess
from pathlib import Path

from scenarios_features import _binary, base, sumocfg, write


def lanechange_duration(dest: Path) -> None:
    """Continuous lane changing without the sublane model: a change takes 3 s, vehicles are between two
    lanes at T."""
    base(dest, "--default.lanenumber", "2", lanechange__duration="3")


def begin_odd(dest: Path) -> None:
    """A begin that is no whole second (7.25 s), quarter-second steps, an odd end, and the route file read
    30 s ahead of the clock (``route-steps``)."""
    base(dest)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml"], begin="7.25", end="297.75",
            step_length="0.25", route_steps="30")


PERSON_TRIPS = """    <vType id="bus" vClass="bus"/>
    <route id="line" edges="A1B1 B1C1 C1D1"/>
    <flow id="bus" type="bus" route="line" line="L1" begin="0" end="300" period="40">
        <stop busStop="bs_a" duration="10" until="20"/>
        <stop busStop="bs_b" duration="10" until="60"/>
    </flow>
    <personFlow id="by_bus" begin="0" end="300" period="15">
        <personTrip from="A0A1" to="D1D2" modes="public"/>
    </personFlow>
    <personFlow id="by_car" begin="0" end="300" period="20">
        <personTrip from="B0B1" to="C2C3" modes="car"/>
    </personFlow>
    <person id="on_foot" depart="60">
        <personTrip from="A2B2" to="C2D2"/>
    </person>
"""
PERSON_TRIP_STOPS = """    <busStop id="bs_a" lane="A1B1_0" startPos="20" endPos="50" lines="L1"/>
    <busStop id="bs_b" lane="C1D1_0" startPos="20" endPos="50" lines="L1"/>
"""


def person_trips(dest: Path) -> None:
    """Intermodal person trips SUMO routes when they depart: by the bus line (``modes="public"``), in a
    car of their own (``modes="car"``), on foot."""
    base(dest)
    stops = write(dest, "stops.add.xml", "additional", PERSON_TRIP_STOPS)
    persons = write(dest, "persons.rou.xml", "routes", PERSON_TRIPS)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", persons], [stops])


CROSSING_NODES = """    <node id="W" x="-300" y="0"/>
    <node id="X" x="0" y="0" type="rail_crossing"/>
    <node id="E" x="300" y="0"/>
    <node id="N" x="0" y="400"/>
    <node id="S" x="0" y="-400"/>
"""
CROSSING_EDGES = """    <edge id="WX" from="W" to="X" numLanes="1" speed="13.89"/>
    <edge id="XE" from="X" to="E" numLanes="1" speed="13.89"/>
    <edge id="EX" from="E" to="X" numLanes="1" speed="13.89"/>
    <edge id="XW" from="X" to="W" numLanes="1" speed="13.89"/>
    <edge id="NX" from="N" to="X" numLanes="1" speed="30" allow="rail"/>
    <edge id="XS" from="X" to="S" numLanes="1" speed="30" allow="rail"/>
"""
CROSSING_DEMAND = """    <vType id="train" vClass="rail" length="100"/>
    <flow id="east" from="WX" to="XE" begin="0" end="300" period="4"/>
    <flow id="west" from="EX" to="XW" begin="0" end="300" period="5"/>
    <flow id="trains" type="train" from="NX" to="XS" begin="20" end="300" period="90"/>
"""


def rail_crossing(dest: Path) -> None:
    """A road crossing a railway at a level crossing (junction type ``rail_crossing``): cars queue while
    a train passes."""
    write(dest, "crossing.nod.xml", "nodes", CROSSING_NODES)
    write(dest, "crossing.edg.xml", "edges", CROSSING_EDGES)
    subprocess.run([_binary("netconvert"), "-n", "crossing.nod.xml", "-e", "crossing.edg.xml", "-o", "net.net.xml"],
                   cwd=dest, check=True, capture_output=True, timeout=600)
    demand = write(dest, "crossing.rou.xml", "routes", CROSSING_DEMAND)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", [demand])


def threads(dest: Path) -> None:
    """SUMO's parallel simulation (``threads 2``)."""
    base(dest, threads="2")


EMERGENCY = """    <vType id="ambulance" vClass="emergency" guiShape="emergency" speedFactor="1.5">
        <param key="has.bluelight.device" value="true"/>
    </vType>
    <flow id="ambulance" type="ambulance" from="A0B0" to="D3C3" begin="0" end="300" period="30"/>
"""


def emergency(dest: Path) -> None:
    """Emergency vehicles with SUMO's bluelight device (the others give way, red lights are passed) among
    the cars, on two lanes a direction with the sublane model the device wants."""
    base(dest, "--default.lanenumber", "2")
    ambulances = write(dest, "emergency.rou.xml", "routes", EMERGENCY)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", ambulances], lateral_resolution="0.8")


def ssm(dest: Path) -> None:
    """SUMO's SSM device on every vehicle (``device.ssm.probability``) with no file named: it writes
    ssm_<vehicle>.xml into the working directory."""
    base(dest, device__ssm__probability="1")


def bike_lanes(dest: Path) -> None:
    """Bicycle lanes beside the car lanes (netgenerate's ``bikelanes.guess``), bicycles among the cars."""
    base(dest, "--bikelanes.guess", "--bikelanes.guess.max-speed", "20", classes=("passenger", "bicycle"))


EMISSIONS = """    <vType id="petrol" vClass="passenger" emissionClass="HBEFA4/PC_petrol_Euro-6ab"/>
    <vType id="diesel_truck" vClass="truck" emissionClass="HBEFA3/HDV_D_EU5"/>
    <vType id="electric" vClass="passenger" emissionClass="Energy/unknown"/>
    <flow id="petrol" type="petrol" from="A0B0" to="D3C3" begin="0" end="300" period="12"/>
    <flow id="trucks" type="diesel_truck" from="D0C0" to="A3A2" begin="0" end="300" period="20"/>
    <flow id="electric" type="electric" from="B3B2" to="C0D0" begin="0" end="300" period="15"/>
"""


def emissions(dest: Path) -> None:
    """vTypes of several emission classes (HBEFA 4 and 3, SUMO's energy model) and every vehicle with an
    emissions device (``device.emissions.probability``)."""
    base(dest)
    classes = write(dest, "emissions.rou.xml", "routes", EMISSIONS)
    sumocfg(dest / "scenario.sumocfg", "net.net.xml", ["passenger.rou.xml", classes],
            device__emissions__probability="1")


# name -> (builder, what it covers, the row's fields over the corpus's defaults), as scenarios_features.FEATURES
MORE_FEATURES = {
    "feat_lanechange_duration": (lanechange_duration, ("continuous lane change",), {}),
    "feat_begin_odd": (begin_odd, ("begin 7.25", "step length 0.25", "route-steps"), {}),
    "feat_person_trips": (person_trips, ("personTrip", "intermodal routing", "buses", "stops"), {}),
    "feat_rail_crossing": (rail_crossing, ("rail crossing", "trains among cars"), {}),
    "feat_threads": (threads, ("parallel simulation (threads)",), {}),
    "feat_emergency": (emergency, ("emergency vehicles", "bluelight device", "sublane model"), {}),
    "feat_ssm": (ssm, ("SSM device", "outputs by default"), {}),
    "feat_bike_lanes": (bike_lanes, ("bicycle lanes", "bicycles"), {}),
    "feat_emissions": (emissions, ("emission classes", "emissions device", "trucks"), {}),
}
