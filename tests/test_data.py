"""Scene recording CLI, shards and the Dataset (real SUMO through libsumo, small scale)."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from sumo_scendiff.data.shards import SceneStore
from sumo_scendiff.map.raster import MAP_CHANNELS

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

CLI = [sys.executable, "-m", "sumo_scendiff.data"]


def run(*args):
    return subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, cross_net):
    out = tmp_path_factory.mktemp("rec") / "d"
    res = run("-n", cross_net, "-o", out, "--scenes", 60, "-s", 3, "--scenes-per-episode", 30)
    assert res.returncode == 0, res.stderr
    return str(out)


def test_recording_is_deterministic_for_a_seed(recorded, cross_net, tmp_path):
    again = tmp_path / "again"
    assert run("-n", cross_net, "-o", again, "--scenes", 60, "-s", 3, "--scenes-per-episode", 30,
               "--workers", 2).returncode == 0
    a, b = SceneStore(recorded), SceneStore(str(again))
    assert len(a) == len(b) == 60
    for i in range(60):
        sa, sb = a.scene(i), b.scene(i)
        assert sa.window == sb.window and np.array_equal(sa.boxes, sb.boxes)
        assert np.array_equal(sa.traj, sb.traj) and np.array_equal(sa.speed, sb.speed)


def test_recorded_scenes_are_consistent(recorded, cross_net):
    from sumo_scendiff.map.network import Network
    store = SceneStore(recorded)
    net = Network.load(cross_net)
    counts = [len(store.scene(i)) for i in range(len(store))]
    assert sum(counts) > 0 and min(counts) >= 0
    for i in range(len(store)):
        s = store.scene(i)
        if not len(s):
            continue
        assert np.all(s.window.contains(s.boxes[:, :2]))       # centres inside the window
        assert np.all(s.traj_mask[:, 2])                       # observed at t = 0 by construction
        assert np.allclose(s.traj[:, 2, :2], s.boxes[:, :2], atol=1e-4)
        world = s.window.scene_to_world(s.boxes[:, :2])
        assert net.on_drivable(world).mean() > 0.95            # SUMO vehicles are on the road
        assert np.all((s.boxes[:, 3] > 1.5) & (s.boxes[:, 3] < 20))


def test_recorded_speeds_are_the_backward_differences_of_the_poses(recorded):
    """The recorder steps SUMO by 1 s and SUMO moves a vehicle by its new speed, so the speed a
    generated scene reports (speeds_from_traj, backward differences) is the recorded one."""
    from sumo_scendiff.generation.generator import speeds_from_traj
    store = SceneStore(recorded)
    errs = []
    for i in range(len(store)):
        s = store.scene(i)
        full = s.traj_mask.all(1)
        v = speeds_from_traj(s.traj[full], s.traj_mask[full])
        errs.append(np.abs(v[:, 1:] - s.speed[full][:, 1:]).ravel())
    errs = np.concatenate(errs)
    assert len(errs) > 100 and np.median(errs) < 0.01 and errs.mean() < 0.1


def test_dataset_items_and_rotation(recorded):
    import torch

    from sumo_scendiff.data.dataset import SceneDataset, collate_scenes
    ds = SceneDataset(recorded, rotate=True, seed=0)
    items = [ds[i] for i in range(4)]
    assert items[0]["map"].shape == (len(MAP_CHANNELS), 128, 128) and items[0]["agents"].shape == (15, 128, 128)
    again = ds[0]
    assert np.array_equal(again["boxes"], items[0]["boxes"])  # same seed/epoch/index -> same sample
    ds.set_epoch(1)
    i = next(k for k in range(len(ds)) if len(ds.store.scene(k)))
    assert not np.allclose(ds[i]["boxes"][:, 2], SceneDataset(recorded, seed=0)[i]["boxes"][:, 2])
    batch = collate_scenes(items)
    assert batch["map"].dtype == torch.float32 and batch["valid"].shape[0] == 4


def test_several_data_directories_read_as_one(recorded, cross_net, tmp_path):
    """`train --data A B`: the scenes of A then B, each resolving its network against its own
    directory (here B sits one level deeper, with a relative network path)."""
    import json
    import shutil

    deeper = tmp_path / "x" / "copy"
    shutil.copytree(recorded, deeper)
    manifest = json.loads((deeper / "manifest.json").read_text())
    for entry in manifest["nets"]:
        entry["path"] = os.path.relpath(cross_net, deeper)
    (deeper / "manifest.json").write_text(json.dumps(manifest))
    one, both = SceneStore(recorded), SceneStore([recorded, str(deeper)])
    assert len(both) == 2 * len(one)
    for i in (0, len(one) - 1):
        assert np.array_equal(both.scene(len(one) + i).boxes, one.scene(i).boxes)
        assert os.path.samefile(both.net_path(len(one) + i), one.net_path(i))
    assert both.net_name(len(one)) == one.net_name(0)


@pytest.mark.parametrize("case", ["missing", "empty", "foreign_routes", "exists"])
def test_bad_input_one_line_exit_2_no_output(tmp_path, cross_net, diagonal_net, case):
    out = tmp_path / "out"
    args = ["-n", cross_net, "-o", out, "--scenes", 5]
    if case == "missing":
        args[1] = tmp_path / "nope.net.xml"
    elif case == "empty":
        (tmp_path / "e.net.xml").write_text("")
        args[1] = tmp_path / "e.net.xml"
    elif case == "foreign_routes":
        rou = tmp_path / "x.rou.xml"
        rou.write_text('<routes><vehicle id="v" depart="0"><route edges="ab"/></vehicle></routes>\n')
        args += ["-r", rou]
    elif case == "exists":
        out.mkdir()
        (out / "mine.txt").write_text("keep me")
    res = run(*args)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    if case == "exists":
        assert (out / "mine.txt").read_text() == "keep me"
    else:
        assert not out.exists() and not os.path.exists(str(out) + ".partial")
    named = {"missing": "nope.net.xml", "empty": "e.net.xml", "foreign_routes": "x.rou.xml", "exists": "out"}
    assert named[case] in res.stderr


def test_rotated_items_keep_only_agents_inside_the_window(recorded):
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.data.dataset import SceneDataset
    ds = SceneDataset(recorded, rotate=True, seed=1)
    for i in range(len(ds)):
        b = ds[i]["boxes"]
        assert np.all(Window(0.0, 0.0).contains(b[:, :2]))


def test_density_range_bounds_every_episode(cross_net, tmp_path):
    from sumo_scendiff.data.record import plan_episodes
    from sumo_scendiff.map.network import Network
    net = Network.load(cross_net)
    default = plan_episodes([net], [None], [0.0], 3000, 0, 300)
    dense = plan_episodes([net], [None], [0.0], 3000, 0, 300, density=(300.0, 800.0))
    assert all(15.0 <= s.density <= 400.0 for _, _, s in default)
    assert all(300.0 <= s.density <= 800.0 for _, _, s in dense)
    assert [s.seed for _, _, s in dense] == [s.seed for _, _, s in default]  # only the density moves
    res = run("-n", cross_net, "-o", tmp_path / "out", "--scenes", 5, "--density", 400, 100)
    assert res.returncode == 2 and "--density 400 100" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "out").exists()


def test_peak_share_draws_that_share_of_episodes_from_the_peak_range(cross_net, tmp_path):
    """Without the option the plan is the one before it; with it, about that share of the episodes
    take a density from the peak range, and every other field of every episode stays."""
    from dataclasses import replace

    from sumo_scendiff.data.record import plan_episodes
    from sumo_scendiff.map.network import Network
    net = Network.load(cross_net)
    default = plan_episodes([net], [None], [0.0], 30000, 0, 100)
    assert plan_episodes([net], [None], [0.0], 30000, 0, 100, peak_share=0.0) == default
    peak = plan_episodes([net], [None], [0.0], 30000, 0, 100, peak_share=0.3, peak_density=(2000.0, 5000.0))
    moved = [p for (_, _, p), (_, _, d) in zip(peak, default) if p.density != d.density]
    assert 0.2 < len(moved) / len(default) < 0.4                 # 300 episodes: 0.3 +- 6 s.d.
    assert all(2000.0 <= p.density <= 5000.0 for p in moved)
    assert all(replace(p, density=d.density) == d for (_, _, p), (_, _, d) in zip(peak, default))
    for flag, values in (("--peak-share", (1.5,)), ("--peak-density", (900, 100)), ("--default-sizes", (-1,))):
        res = run("-n", cross_net, "-o", tmp_path / "out", "--scenes", 5, flag, *values)
        assert res.returncode == 2 and flag in res.stderr and "Traceback" not in res.stderr
        assert len(res.stderr.strip().splitlines()[-1:]) == 1 and not (tmp_path / "out").exists()


def test_default_sizes_put_sumo_default_vehicle_types_in_the_fleet(recorded, cross_net, tmp_path):
    """--default-sizes 1: every class in SUMO's own vType, a passenger car 5 m x 1.8 m (SUMO's
    defaults); the manifest says so (and a recording without the option does not mention it), and
    its episodes run again to the same scenes."""
    import json

    from sumo_scendiff.data.rerecord import rerecorded
    out = tmp_path / "default"
    res = run("-n", cross_net, "-o", out, "--scenes", 20, "-s", 4, "--scenes-per-episode", 20,
              "--density", 300, 300, "--default-sizes", 1)
    assert res.returncode == 0, res.stderr
    store = SceneStore(str(out))
    cars = np.concatenate([s.boxes[s.vclass == 0, 3:5] for s in map(store.scene, range(len(store)))])
    assert len(cars) > 20 and np.allclose(cars, [5.0, 1.8])
    with open(out / "manifest.json") as f:
        assert [e["default_sizes"] for e in json.load(f)["episodes"]] == [1.0]
    with open(os.path.join(recorded, "manifest.json")) as f:
        assert all("default_sizes" not in e for e in json.load(f)["episodes"])
    windows = [store.scene(i).window for i in range(len(store))]
    again = rerecorded(str(out), windows, (0.0,))[0.0]
    assert all(np.array_equal(a.boxes, store.scene(i).boxes) for i, a in enumerate(again))


def test_episodes_run_again_reproduce_their_scenes_whole_turned_windows_and_later(recorded):
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import crop_to_window, rotate_scene
    from sumo_scendiff.data.rerecord import rerecorded
    store = SceneStore(recorded)
    scenes = [store.scene(i) for i in range(len(store))]
    again = rerecorded(recorded, [s.window for s in scenes], (0.0, 30.0))
    for s, a in zip(scenes, again[0.0]):          # the same windows at the same instants: the same scenes
        assert a.time == s.time and np.array_equal(a.boxes, s.boxes) and np.array_equal(a.traj, s.traj)
    later = again[30.0]
    assert [a.time for a in later] == [s.time + 30.0 for s in scenes]
    assert sum(not np.array_equal(a.boxes, s.boxes) for a, s in zip(later, scenes)) > len(scenes) // 2
    # a turned window recorded whole holds the cropped scene's agents, and the corners' too
    turned = [Window(s.window.cx, s.window.cy, s.window.yaw + 0.7, s.window.size) for s in scenes]
    whole = rerecorded(recorded, turned, (0.0,))[0.0]
    cropped = [crop_to_window(rotate_scene(s, 0.7)) for s in scenes]
    for c, w in zip(cropped, whole):
        for b in c.boxes:
            assert np.abs(w.boxes[:, :3] - b[:3]).max(axis=1).min() < 1e-3
    assert sum(map(len, whole)) > sum(map(len, cropped))
    # cached beside the data directory, keyed by the windows
    assert len([f for f in os.listdir(os.path.dirname(recorded)) if "-again" in f]) == 3
    assert all(np.array_equal(a.boxes, b.boxes)
               for a, b in zip(rerecorded(recorded, turned, (0.0,))[0.0], whole))


def test_recorded_circles_make_turned_training_windows_whole(recorded, cross_net, tmp_path):
    """A recording holds each window's circumscribed circle: its square is the ``--square``
    recording exactly, and the window turned by any angle and cropped (what training sees) is the
    turned window as SUMO holds it (the episode recorded again there), corners included."""
    import json

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.core.scene import crop_to_window, rotate_scene
    from sumo_scendiff.data.dataset import SceneDataset
    from sumo_scendiff.data.rerecord import rerecorded
    square = tmp_path / "square"
    assert run("-n", cross_net, "-o", square, "--scenes", 60, "-s", 3, "--scenes-per-episode", 30,
               "--square").returncode == 0
    assert json.loads((square / "manifest.json").read_text())["disc"] is False
    assert json.loads(open(os.path.join(recorded, "manifest.json")).read())["disc"] is True
    discs, squares = SceneStore(recorded), SceneStore(str(square))
    for i in range(len(squares)):
        a, b = discs.scene(i), squares.scene(i)
        assert a.window == b.window and np.array_equal(a.boxes, b.boxes) and np.array_equal(a.traj, b.traj)
        assert np.array_equal(squares.scene(i, disc=True).boxes, b.boxes)  # a square recording has no more
    circles = [discs.scene(i, disc=True) for i in range(len(discs))]
    assert sum(map(len, circles)) > sum(len(discs.scene(i)) for i in range(len(discs)))
    angle = 0.7
    turned = [Window(s.window.cx, s.window.cy, s.window.yaw + angle, s.window.size) for s in circles]
    truth = rerecorded(recorded, turned, (0.0,))[0.0]
    cut = [crop_to_window(rotate_scene(s, angle)) for s in circles]
    assert sum(map(len, truth)) > sum(len(crop_to_window(rotate_scene(squares.scene(i), angle)))
                                      for i in range(len(squares)))
    for c, t in zip(cut, truth):
        assert len(c) == len(t)
        assert np.allclose(np.sort(c.boxes[:, 0]), np.sort(t.boxes[:, 0]), atol=1e-3)
    ds = SceneDataset(recorded, rotate=True, seed=0)                # the dataset serves the circle
    assert sum(len(ds[i]["boxes"]) for i in range(len(ds))) > sum(
        len(x["boxes"]) for x in (SceneDataset(str(square), rotate=True, seed=0)[i] for i in range(len(ds))))


def test_vehicles_off_the_road_are_not_recorded():
    """A teleporting vehicle is off the road: SUMO reports INVALID_DOUBLE_VALUE for its position
    and speed. The tracker must leave it out (its step's mask stays False), not record it at
    (-2^30, -2^30), where an ego window could be centred on it."""
    import libsumo

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.data.record import INVALID, _Tracker
    assert INVALID == libsumo.INVALID_DOUBLE_VALUE
    c = libsumo.constants
    states = [{"a": {c.VAR_POSITION: (10.0, 0.0), c.VAR_ANGLE: 90.0, c.VAR_SPEED: 5.0},
               "b": {c.VAR_POSITION: (20.0, 0.0), c.VAR_ANGLE: 90.0, c.VAR_SPEED: 5.0}}
              for _ in range(5)]
    states[3]["b"] = {c.VAR_POSITION: (INVALID, INVALID), c.VAR_ANGLE: INVALID, c.VAR_SPEED: INVALID}

    class Sim:  # the few calls the tracker makes, answering as libsumo does
        constants = c
        k = 0

        class simulation:
            getDepartedIDList = getArrivedIDList = staticmethod(lambda: [])

        class vehicle:
            getTypeID = staticmethod(lambda vid: "car")
            getVehicleClass = staticmethod(lambda vid: "passenger")
            getLength = staticmethod(lambda vid: 5.0)
            getWidth = staticmethod(lambda vid: 1.8)

    sim = Sim()
    sim.vehicle.getAllSubscriptionResults = lambda: states[sim.k]
    tracker = _Tracker(sim)
    for sim.k in range(5):
        tracker.step()
    assert "b" not in tracker.steps[3] and "b" in tracker.steps[2]
    scene = tracker.scene(Window(15.0, 0.0, 0.0), "x", 0.0)
    assert len(scene) == 2 and scene.traj_mask.sum(1).tolist() == [5, 4]
    assert np.abs(scene.traj[scene.traj_mask]).max() < 100 and scene.speed.max() == 5.0


def _children(pid: int) -> list[int]:
    kids = []
    for d in os.listdir("/proc"):
        try:
            with open(f"/proc/{d}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            kids.append(int(d))
    return kids


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_a_terminated_recording_stops_its_workers_and_resumes_to_the_same_scenes(cross_net, tmp_path):
    import signal
    import time
    args = ["-n", cross_net, "--scenes", 120, "-s", 5, "--scenes-per-episode", 10]
    out = tmp_path / "d"
    partial = tmp_path / "d.partial"
    p = subprocess.Popen(CLI + [str(a) for a in args + ["-o", out, "--workers", 2]],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while not (partial.is_dir() and any(n.endswith(".npz") and ".tmp" not in n for n in os.listdir(partial))):
            assert p.poll() is None and time.time() < deadline, "the recording ended before its first episode"
            time.sleep(0.02)
        workers = _children(p.pid)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:  # a failed test leaves no recording behind
            p.kill()
            p.wait()
    assert p.returncode == 130
    assert "Traceback" not in err and "--resume" in err.strip().splitlines()[-1]
    deadline = time.time() + 10
    while any(_alive(w) for w in workers) and time.time() < deadline:
        time.sleep(0.05)
    assert len(workers) >= 2 and not any(_alive(w) for w in workers), "workers outlived the recording"
    assert not out.exists(), "an interrupted recording must not look complete"
    kept = [n for n in os.listdir(partial) if n.startswith("shard-") and ".tmp" not in n]
    assert 1 <= len(kept) < 12

    res = run(*args, "-o", out, "--workers", 2, "--resume")
    assert res.returncode == 0, res.stderr
    assert not partial.exists() and not any(".tmp" in n for n in os.listdir(out))
    res = run(*args, "-o", tmp_path / "whole")
    assert res.returncode == 0, res.stderr
    resumed, whole = SceneStore(str(out)), SceneStore(str(tmp_path / "whole"))
    assert len(resumed) == len(whole) == 120
    for i in range(len(whole)):
        a, b = resumed.scene(i), whole.scene(i)
        assert a.time == b.time and np.array_equal(a.boxes, b.boxes) and np.array_equal(a.traj, b.traj)
