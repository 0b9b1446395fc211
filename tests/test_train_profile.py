"""The recorder's speed-ups record the same windows, and benchmarks/train_profile.py's phases add up.

The recorder converts each step's vehicles at once and skips the warm-up steps no window reads
(benchmarks/train_profile.py measured the per-vehicle conversion as its largest cost): a
recording must not change by a bit. The reference below is the recorder's per-vehicle loop as it
was, run in the same real SUMO episode.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from sumo_scendiff.core.geometry import sumo_to_pose
from sumo_scendiff.core.scene import Scene
from sumo_scendiff.data import record
from sumo_scendiff.map.network import Network

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class PerVehicleTracker(record._Tracker):
    """Every step's states taken, one vehicle at a time (the recorder before its speed-ups)."""

    def step(self, poses: bool = True) -> None:
        t = self.traci
        for vid in t.simulation.getDepartedIDList():
            t.vehicle.subscribe(vid, (t.constants.VAR_POSITION, t.constants.VAR_ANGLE, t.constants.VAR_SPEED))
        for vid in t.simulation.getArrivedIDList():
            self.vtype_of.pop(vid, None)
        c = t.constants
        state = {}
        for vid, r in t.vehicle.getAllSubscriptionResults().items():
            length, width, vcls = self._static(vid)
            x, y = r[c.VAR_POSITION]
            if vcls < 0 or record.INVALID in (x, y, r[c.VAR_SPEED]):
                continue
            cx, cy, yaw = sumo_to_pose(x, y, r[c.VAR_ANGLE], length)
            state[vid] = (float(cx), float(cy), float(yaw), float(r[c.VAR_SPEED]), length, width, vcls)
        self.steps.append(state)
        self.lights.append({i: t.trafficlight.getRedYellowGreenState(i) for i in self.light_ids})

    def scene(self, window, net_name, time, disc=False) -> Scene:
        """The recorder's scene (which agents: unchanged), its arrays made again one pose at a time."""
        fast = super().scene(window, net_name, time, disc)
        now = self.steps[record.T0]
        ids = [vid for vid in now if np.hypot(*window.world_to_scene(now[vid][:2])) <= window.size / np.sqrt(2.0)]
        traj, mask, speed = np.zeros((len(ids), 5, 3)), np.zeros((len(ids), 5), bool), np.zeros((len(ids), 5))
        for a, vid in enumerate(ids):
            for k, st in enumerate(self.steps):
                if vid in st:
                    traj[a, k] = (*window.world_to_scene(st[vid][:2]), window.yaw_to_scene(st[vid][2]))
                    speed[a, k], mask[a, k] = st[vid][3], True
        sizes = [now[vid][4:6] for vid in ids]
        return Scene(window, np.column_stack([traj[:, record.T0], np.reshape(sizes, (-1, 2))]), traj, mask, speed,
                     np.array([now[vid][6] for vid in ids], np.int8), net_name, time, fast.meta)


def _episode(net_path: str, tracker, monkeypatch) -> list[Scene]:
    monkeypatch.setattr(record, "_Tracker", tracker)
    spec = record.EpisodeSpec(seed=3, scenes=24, density=400.0, warmup=40.0, duration=300.0, sample_every=2.0,
                              disc=True)
    return record.record_episode(Network.load(net_path), spec)


def test_the_recorders_speed_ups_record_the_same_windows(cross_net, monkeypatch):
    fast = _episode(cross_net, record._Tracker, monkeypatch)
    slow = _episode(cross_net, PerVehicleTracker, monkeypatch)
    assert len(fast) == len(slow) == 24
    assert sum(len(s) for s in fast) > 24   # windows with traffic in them
    for a, b in zip(fast, slow):
        assert a.window == b.window and a.time == b.time and a.meta == b.meta
        for key in ("boxes", "traj", "traj_mask", "speed", "vclass"):
            x, y = getattr(a, key), getattr(b, key)
            assert x.dtype == y.dtype and np.array_equal(x, y), key


@pytest.mark.slow
def test_the_profile_of_a_training_step_adds_up(tmp_path):
    """The autoencoder stage of configs/scendiff.json, one measured step: its phases sum to the
    step's CPU time, and the data, forward, backward and optimiser each take some of it."""
    data = tmp_path / "data"
    subprocess.run([sys.executable, "-m", "sumo_scendiff.data", "-n", os.path.join(ROOT, "networks", "grid3x3_1lane.net.xml"),
                    "-o", str(data), "--scenes", "16", "-s", "0", "--scenes-per-episode", "16"],
                   cwd=ROOT, check=True, capture_output=True)
    work = tmp_path / "work"
    work.mkdir()
    subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "train_profile.py"), "--data", str(data),
                    "--steps", "1", "--warmup", "1", "--child", "autoencoder", "--work", str(work)],
                   cwd=ROOT, check=True, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    out = json.loads((work / "autoencoder.json").read_text())
    rows = {r["phase"]: r["cpu_s"] for r in out["rows"]}
    assert sum(rows.values()) + out["backward_blocks_s"] == pytest.approx(out["cpu_s_per_step"], rel=1e-3)
    assert out["batch_per_process"] == 8
    for phase in ("data: map raster (render_map)", "forward: E.body.0", "optimizer: clip, step, weight average"):
        assert rows[phase] > 0, phase
    assert out["backward_blocks_s"] > 0
    e0 = next(r for r in out["rows"] if r["phase"] == "forward: E.body.0")
    assert e0["res"] == 128 and e0["gflop"] > 0 and e0["params"] > 0
