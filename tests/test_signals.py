"""Traffic-light states: read from the network's links, recorded per scene, drawn as map channels."""
import numpy as np

from sumo_scendiff.core.geometry import Window, metres_to_pixels
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.map.network import Network
from sumo_scendiff.map.raster import MAP_CHANNELS, render_map
from sumo_scendiff.map.signals import approach, decode_states, encode_states

GO, STOP = MAP_CHANNELS.index("signal_go"), MAP_CHANNELS.index("signal_stop")


def _value(m, channel, xy):
    col, row = np.round(metres_to_pixels(np.array(xy, float), 100.0, (128, 128))).astype(int)
    return m[channel, row, col]


def test_links_of_a_signalised_crossing(cross_net):
    net = Network.load(cross_net)
    links = net.signal_links
    assert {ln.tls for ln in links} == {"c"}
    assert sorted(ln.index for ln in links) == list(range(len(links)))
    assert all(not net.lanes[ln.lane].internal and net.lanes[ln.via].internal for ln in links)
    assert net.lights_in(Window(0.0, 0.0, 0.0, 100.0)) == ["c"]
    assert net.lights_in(Window(180.0, 150.0, 0.0, 20.0)) == []


def test_states_are_drawn_on_approach_and_junction_and_unknown_is_zero(cross_net):
    net = Network.load(cross_net)
    w = Window(0.0, 0.0, 0.0, 100.0)
    n = len(net.signal_links)
    # the eastbound approach (lane wc_0, y < 0 in right-hand traffic) green, everything else red
    state = "".join("G" if net.lanes[ln.lane].id == "wc_0" else "r"
                    for ln in sorted(net.signal_links, key=lambda ln: ln.index))
    assert len(state) == n
    plain = render_map(net, w)
    lit = render_map(net, w, signals={"c": state})
    assert (plain[[GO, STOP]] == 0).all()
    others = [i for i in range(len(MAP_CHANNELS)) if i not in (GO, STOP)]
    assert np.array_equal(plain[others], lit[others])   # the static map does not change
    east = approach(net.lanes[net.lane_index["wc_0"]].shape)
    mid = east.mean(0)                                    # window centred on the origin, yaw 0
    assert _value(lit, GO, mid) == 1.0 and _value(lit, STOP, mid) == 0.0
    west = approach(net.lanes[net.lane_index["ec_0"]].shape).mean(0)
    assert _value(lit, STOP, west) == 1.0 and _value(lit, GO, west) == 0.0
    # amber is half a stop; a light the window does not show is ignored
    amber = render_map(net, w, signals={"c": "y" * n, "elsewhere": "G"})
    assert _value(amber, STOP, west) == 0.5 and amber[GO].max() == 0.0


def test_recorded_scenes_carry_the_light_states_through_a_shard(cross_net, tmp_path):
    from sumo_scendiff.data.dataset import SceneDataset
    from sumo_scendiff.data.record import EpisodeSpec, record_episode
    from sumo_scendiff.data.shards import Shard, write_manifest, write_shard
    net = Network.load(cross_net)
    scenes = record_episode(net, EpisodeSpec(seed=3, scenes=6, density=800.0, warmup=20.0, duration=120.0,
                                             sample_every=20.0, windows_per_sample=1, p_ego=0.0))
    assert scenes
    n = len(net.signal_links)
    states = [s.meta["signals"] for s in scenes]
    assert all(set(st) == {"c"} and len(st["c"]) == n for st in states)
    assert len({st["c"] for st in states}) > 1   # the light changes between scenes 20 s apart
    centre = Scene.empty(Window(0.0, 0.0, 0.0, 100.0), net="cross", time=0.0)
    centre.meta["signals"] = states[0]      # a window on the junction, for the dataset below
    entry = write_shard(str(tmp_path / "shard-000-0000.npz"), scenes + [centre], 0)
    shard = Shard.load(str(tmp_path / entry["file"]))
    assert [shard.scene(i).meta["signals"] for i in range(len(shard))] == states + [states[0]]
    assert decode_states(encode_states(states[0])) == states[0] and decode_states("") == {}
    write_manifest(str(tmp_path), [{"name": "cross", "path": cross_net, "sha256": ""}], [entry])
    seen = SceneDataset(str(tmp_path), rotate=False)[len(scenes)]["map"]
    hidden = SceneDataset(str(tmp_path), rotate=False, p_no_signals=1.0)[len(scenes)]["map"]
    assert seen[[GO, STOP]].sum() > 0 and hidden[[GO, STOP]].sum() == 0


def test_the_generator_takes_the_lights_only_when_asked(cross_net):
    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    net = Network.load(cross_net)
    state = "G" * len(net.signal_links)
    w = [Window(0.0, 0.0, 0.0, 100.0)]
    off = ScenarioGenerator.load(None, GenerationConfig(steps=2)).generate(net, w, signals={"c": state})[0]
    on = ScenarioGenerator.load(None, GenerationConfig(steps=2, signals=True)).generate(
        net, w, signals={"c": state, "elsewhere": "r"})[0]
    assert "signals" not in off.meta
    assert on.meta["signals"] == {"c": state}   # the window's lights, as scene.json records them
    assert GenerationConfig(signals=True).record(ScenarioGenerator.load(None))["signals"] is True


def test_a_via_lane_without_area_is_skipped_not_a_crash(cross_net):
    """Some real networks have zero-length internal lanes (an empty polygon: berlin_doerpfeldstr):
    their link is still drawn on its approach, the via lane has nothing to fill."""
    net = Network.load(cross_net)
    link = next(ln for ln in net.signal_links if net.lanes[ln.lane].id == "wc_0")
    net.lanes[link.via].ring = np.zeros((0, 2))
    # as Network.load leaves a lane without area out of its lane index
    every = net.lanes_in
    net.lanes_in = lambda window: np.array([i for i in every(window) if i != link.via], np.int64)
    state = "".join("G" if ln is link else "r" for ln in sorted(net.signal_links, key=lambda ln: ln.index))
    lit = render_map(net, Window(0.0, 0.0, 0.0, 100.0), signals={"c": state})
    assert _value(lit, GO, approach(net.lanes[link.lane].shape).mean(0)) == 1.0


def test_a_queue_at_red_stands_up_to_the_first_vehicle_approaching(cross_net):
    """Given the lights, the vehicles the model drew slow before a red stop line stand (from -1 s
    on: SUMO's speed at t = 0 is the last second's displacement), from the line back up to the first
    one faster than CREEP; that one and those behind it keep their motion, as does a queue at green."""
    from sumo_scendiff.core.geometry import T0, TIMES
    from sumo_scendiff.generation.red_queues import CREEP, red_lanes, stand_at_red
    net = Network.load(cross_net)
    west = next(ln for ln in net.signal_links if net.lanes[ln.lane].edge == "wc")
    lane = net.lanes[west.lane]
    red = "".join("r" if net.lanes[ln.lane].edge == "wc" else "G"
                  for ln in sorted(net.signal_links, key=lambda ln: ln.index))
    assert red_lanes(net, {"c": red}) == {west.lane}
    w = Window(-60.0, 0.0, 0.0, 100.0)
    speeds = [0.6, 2.0, CREEP + 4.0, 1.0]                 # from the line back: 3, 12, 21, 30 m
    boxes, traj = [], []
    for k, v in enumerate(speeds):
        front = lane.length - 3.0 - 9.0 * k
        (x, y), yaw = net.lane_pose(west.lane, front - 2.5)
        sx, sy = w.world_to_scene(np.array([x, y]))
        boxes.append([sx, sy, yaw, 5.0, 1.8])
        traj.append([[sx + v * (t - T0), sy, yaw] for t in range(len(TIMES))])
    mask = np.ones((4, len(TIMES)), bool)
    from sumo_scendiff.core.scene import speeds_from_traj
    traj = np.array(traj)
    scene = Scene(w, np.array(boxes), traj, mask, speeds_from_traj(traj, mask), np.zeros(4))
    out = stand_at_red(scene, net, {"c": red})
    assert out.meta["stood_at_red"] == [True, True, False, False]
    assert out.select([1, 2]).meta["stood_at_red"] == [True, False]
    assert np.allclose(out.speed[:2, T0:], 0.0) and np.allclose(out.speed[2:], scene.speed[2:])
    assert np.allclose(out.traj[:2, 0], scene.traj[:2, 0])            # its -2 s pose is the model's
    assert np.allclose(out.traj[:2, T0 - 1:], scene.traj[:2, T0:T0 + 1])
    green = stand_at_red(scene, net, {"c": "G" * len(red)})
    assert np.array_equal(green.traj, scene.traj) and "stood_at_red" not in green.meta
