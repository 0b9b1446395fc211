"""Hand-off statistics: SUMO's collision events counted and broken down (real libsumo)."""
from __future__ import annotations

from sumo_scendiff.sim.rollout import rollout


def _host_behind_standing_agent(sim, cross_net) -> None:
    """SUMO started on the crossing with a standing agent and a host 90 m behind at 13 m/s that
    cannot stop in time (no safe-speed checks)."""
    sim.start(["sumo", "-n", cross_net, "--no-step-log", "--no-warnings", "--step-length", "0.5",
               "--collision.check-junctions", "true", "--collision.action", "remove"])
    sim.route.add("r", ["wc", "ce"])
    sim.vehicle.add("agent", "r", depart="now", departPos="150", departSpeed="0")
    sim.vehicle.add("host", "r", depart="now", departPos="60", departSpeed="13")
    sim.simulationStep()
    sim.vehicle.setSpeed("agent", 0.0)
    sim.vehicle.setSpeedMode("host", 0)
    sim.vehicle.setSpeed("host", 13.0)


def test_a_host_vehicle_running_into_a_standing_agent_is_counted_as_such(cross_net):
    import libsumo as sim
    _host_behind_standing_agent(sim, cross_net)
    try:
        stats = rollout(sim, ["agent"], seconds=8.0, brake_window=10.0)
    finally:
        sim.close()
    assert stats.agents == 1 and stats.collisions == 1
    assert stats.collisions_host == 1 and stats.collisions_host_behind == 1   # SUMO: the follower collides
    assert stats.collisions_junction == 0 and stats.collisions_early == 1
    assert stats.as_dict()["collisions_per_100"] == 100.0


def test_an_event_tracer_records_who_collided_where_and_how_they_got_there(cross_net):
    """``rollout(..., tracer=EventTracer)``: the same counts, and each collision in detail (both
    parties, whether each is an agent, their last steps), the host-only collisions aside."""
    import libsumo as sim

    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.events import EventTracer
    net = Network.load(cross_net)
    _host_behind_standing_agent(sim, cross_net)
    try:
        tracer = EventTracer(sim, net, ["agent"], seeded={"agent": {"lane": "wc_0"}}, label={"window": 0})
        stats = rollout(sim, ["agent"], seconds=8.0, brake_window=10.0, tracer=tracer)
    finally:
        sim.close()
    assert stats.collisions == 1
    (ev,) = [e for e in tracer.events if e["kind"] == "collision"]
    assert ev["window"] == 0 and ev["lane"] == "wc_0" and 0.0 < ev["t"] <= 8.0
    assert ev["collider"]["id"] == "host" and not ev["collider"]["agent"]
    assert ev["victim"]["id"] == "agent" and ev["victim"]["agent"] and ev["victim"]["seed"] == {"lane": "wc_0"}
    assert ev["collider"]["hist"] and ev["collider"]["hist"][-1][1] == "wc_0"    # (t, lane, pos, speed, lat)
    assert tracer.others == []
