"""Record scenes from a running SUMO simulation (libsumo, in-process).

One *episode* = one SUMO run on one network with one demand: warm up, then every ``sample_every``
seconds pick windows — centred on a random vehicle (the "ego", as the paper centres on the AV) or on a
random road point — and record every vehicle whose box centre lies in the window, with its poses at
t = -2, -1, 0, +1, +2 s. With ``EpisodeSpec.disc`` (the data CLI's default) the scene holds every
vehicle within the circle through the window's corners instead: training turns each window by a
random angle, and the turned square is then whole (a recorded square cropped to it misses its
corners, up to 17 % of the area at 45°). A 5-step ring buffer of vehicle states makes the future available: the scene
at time T - 2 is cut when the simulation reaches T.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from collections import deque
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from ..core.geometry import T0, TIMES, Window, sumo_to_pose
from ..core.scene import Scene
from ..core.tools import sumo_binary
from ..map.network import Network
from .demand import RandomDemand, random_trips, write_vtypes
from .shards import write_shard

_VCLASS = {"passenger": 0, "private": 0, "taxi": 0, "evehicle": 0, "emergency": 0, "delivery": 1,
           "truck": 2, "trailer": 2, "coach": 3, "bus": 3, "motorcycle": 4, "moped": 4}
KIND_ROAD, KIND_EGO = 0, 1  # window centred on a random road point / on a vehicle
# what libsumo / traci report for a vehicle off the road (teleporting): neither a position nor a
# speed. Recorded as such, a window could be centred on it, with every teleporting vehicle stacked
# at (-2^30, -2^30) (3 % of the windows of data/val_organic before this check)
INVALID = -1073741824.0
# bumped when what a recording holds changes (2: vehicles off the road left out; 3: traffic-light
# states); part of the key of the evaluation's cached ground truth, so that a cache recorded before is
# recorded again
RECORDER_VERSION = 3

DENSITY = (15.0, 400.0)  # veh/h/km of lane: from nearly empty streets to congestion
PEAK_DENSITY = (300.0, 1000.0)  # veh/h/km of lane: peak hour, queues at lights (most networks gridlock above)


@dataclass(frozen=True)
class EpisodeSpec:
    seed: int
    scenes: int                         # scenes to record in this episode
    routes: str | None = None           # the net's own demand; None -> random trips
    density: float = 100.0              # random demand: vehicles / h / km of lane
    begin: float = 0.0                  # simulation start (own demand: first departure)
    warmup: float = 300.0               # seconds simulated before the first scene
    duration: float = 1800.0            # at most this many seconds recorded
    sample_every: float = 3.0           # seconds between sampling instants
    windows_per_sample: int = 2
    p_ego: float = 0.6                  # fraction of windows centred on a vehicle
    window_size: float = 100.0
    disc: bool = False                  # record the window's circumscribed circle, not its square
    default_sizes: float = 0.0          # random demand: share of the fleet in SUMO's default vTypes


LATER_FIELDS = ("default_sizes",)   # EpisodeSpec's fields that recordings made before them lack


def spec_entry(spec: EpisodeSpec) -> dict:
    """``spec`` as a manifest stores it: a field of :data:`LATER_FIELDS` only when it differs from
    its default, so that a recording that does not use it has the manifest it had."""
    defaults = {f.name: f.default for f in fields(EpisodeSpec)}
    return {k: v for k, v in asdict(spec).items() if k not in LATER_FIELDS or v != defaults[k]}


class _Tracker:
    """Vehicle states of the last five 1-s steps: {id: (cx, cy, yaw, speed, length, width, vclass)},
    and the traffic lights' states at each: {tls id: state string}."""

    def __init__(self, traci, net: Network | None = None):
        self.traci = traci
        self.net = net
        self.steps: deque[dict] = deque(maxlen=len(TIMES))
        self.lights: deque[dict] = deque(maxlen=len(TIMES))
        self.light_ids = list(traci.trafficlight.getIDList()) if net is not None else []
        self.types: dict[str, tuple[float, float, int]] = {}
        self.vtype_of: dict[str, str] = {}

    def _static(self, vid: str):
        v = self.traci.vehicle
        tid = self.vtype_of.get(vid)
        if tid is None:
            tid = self.vtype_of[vid] = v.getTypeID(vid)
        if tid not in self.types:
            vcls = v.getVehicleClass(vid)
            self.types[tid] = (v.getLength(vid), v.getWidth(vid), _VCLASS.get(vcls, -1))
        return self.types[tid]

    def step(self, poses: bool = True) -> None:
        """Take the states of this step. ``poses`` False (a warm-up step no scene will read) keeps
        the subscriptions only: no state is converted or kept."""
        t = self.traci
        for vid in t.simulation.getDepartedIDList():
            t.vehicle.subscribe(vid, (t.constants.VAR_POSITION, t.constants.VAR_ANGLE,
                                      t.constants.VAR_SPEED))
        for vid in t.simulation.getArrivedIDList():
            self.vtype_of.pop(vid, None)
        if not poses:
            return
        res = t.vehicle.getAllSubscriptionResults()
        pos = t.constants.VAR_POSITION
        ang, spd = t.constants.VAR_ANGLE, t.constants.VAR_SPEED
        ids, rows = [], []
        for vid, r in res.items():
            length, width, vcls = self._static(vid)
            if vcls < 0:
                continue  # bicycles, pedestrians' vehicles, trains: not recorded
            x, y = r[pos]
            if INVALID in (x, y, r[spd]):
                continue  # off the road: teleporting (SUMO reports no position or speed then)
            ids.append(vid)
            rows.append((x, y, r[ang], length, r[spd], width, vcls))
        # every vehicle's pose converted at once: sumo_to_pose's per-vehicle arithmetic, on arrays
        a = np.array([r[:4] for r in rows], np.float64).reshape(-1, 4)
        cx, cy, yaw = (v.tolist() for v in sumo_to_pose(a[:, 0], a[:, 1], a[:, 2], a[:, 3]))
        self.steps.append({vid: (cx[k], cy[k], yaw[k], float(r[4]), r[3], r[5], r[6])
                           for k, (vid, r) in enumerate(zip(ids, rows))})
        self.lights.append({i: t.trafficlight.getRedYellowGreenState(i) for i in self.light_ids})

    def signals(self, window: Window) -> dict[str, str]:
        """States at t = 0 of the lights controlling a link within reach of ``window`` turned by any
        angle (its circumscribed square)."""
        if self.net is None or not self.lights:
            return {}
        reach = Window(window.cx, window.cy, 0.0, window.size * np.sqrt(2.0))
        now = self.lights[T0] if len(self.lights) > T0 else self.lights[-1]
        return {i: now[i] for i in self.net.lights_in(reach) if i in now}

    def scene(self, window: Window, net_name: str, time: float, disc: bool = False) -> Scene:
        """Vehicles whose centre lies in ``window`` at the middle step (t = 0); with ``disc``, within
        the window's circumscribed circle (inside the window turned by any angle about its centre)."""
        now = self.steps[T0]
        ids = list(now)
        signals = self.signals(window)
        if not ids:
            scene = Scene.empty(window, net=net_name, time=time)
            scene.meta["signals"] = signals
            return scene
        local = window.world_to_scene(np.array([now[i][:2] for i in ids]))
        if disc:
            inside = np.hypot(local[:, 0], local[:, 1]) <= window.size / np.sqrt(2.0)
        else:
            inside = window.contains(local)
        ids = [i for i, k in zip(ids, inside) if k]
        n = len(ids)
        traj = np.zeros((n, len(TIMES), 3))
        mask = np.zeros((n, len(TIMES)), bool)
        speed = np.zeros((n, len(TIMES)))
        for k, st in enumerate(self.steps):   # each step's agents converted at once
            seen = [a for a, vid in enumerate(ids) if vid in st]
            if not seen:
                continue
            s = np.array([st[ids[a]][:4] for a in seen], np.float64)
            traj[seen, k, :2] = window.world_to_scene(s[:, :2])
            traj[seen, k, 2] = window.yaw_to_scene(s[:, 2])
            speed[seen, k] = s[:, 3]
            mask[seen, k] = True
        sizes = np.array([now[v][4:6] for v in ids]).reshape(n, 2)
        vclass = np.array([now[v][6] for v in ids], dtype=np.int8)
        boxes = np.concatenate([traj[:, T0], sizes], axis=1)
        return Scene(window, boxes, traj, mask, speed, vclass, net_name, time, {"signals": signals})


def _sumo_cmd(net: Network, routes: str, vtypes: str | None, spec: EpisodeSpec) -> list[str]:
    cmd = [sumo_binary("sumo"), "-n", net.path, "-r", routes, "-b", f"{spec.begin:g}",
           "--seed", str(spec.seed % (2 ** 31)), "--step-length", "1", "--no-step-log", "true",
           "--no-warnings", "true", "--ignore-route-errors", "true", "--time-to-teleport", "300",
           "--collision.action", "warn", "--duration-log.disable", "true"]
    if vtypes:
        cmd += ["--additional-files", vtypes]
    return cmd


@contextlib.contextmanager
def _simulation(net: Network, spec: EpisodeSpec, extra_seconds: float = 0.0):
    """libsumo running ``spec``'s episode (its random trips written to a temporary directory
    lasting ``extra_seconds`` beyond the episode), closed on exit."""
    import libsumo as traci

    with tempfile.TemporaryDirectory(prefix="scendiff-") as tmp:
        vtypes = None
        routes = spec.routes
        if routes is None:
            vtypes = write_vtypes(os.path.join(tmp, "vtypes.add.xml"), spec.default_sizes)
            # a longer end draws the same trips first, then more (randomTrips draws them in order)
            end = spec.warmup + spec.duration + 10 + extra_seconds
            routes = random_trips(net.path, os.path.join(tmp, "trips.rou.xml"),
                                  RandomDemand(spec.density, end, spec.seed))
        traci.start(_sumo_cmd(net, routes, vtypes, spec))
        try:
            yield traci
        finally:
            traci.close()


def record_episode(net: Network, spec: EpisodeSpec, progress=None) -> list[Scene]:
    """Run one SUMO episode and return up to ``spec.scenes`` scenes (fewer if the demand runs dry)."""
    rng = np.random.default_rng(spec.seed)
    scenes: list[Scene] = []
    with _simulation(net, spec) as traci:
        tracker = _Tracker(traci, net)
        t_end = spec.begin + spec.warmup + spec.duration
        next_sample = spec.begin + spec.warmup
        while len(scenes) < spec.scenes:
            traci.simulationStep()
            now = traci.simulation.getTime()
            # no pose is read before the first sample's five steps (warm-up): subscriptions only
            tracker.step(poses=now + 2.0 + len(TIMES) >= next_sample)
            if now >= t_end or traci.simulation.getMinExpectedNumber() == 0:
                break
            t0 = now - 2.0  # the middle of the ring buffer
            if len(tracker.steps) < len(TIMES) or t0 < next_sample:
                continue
            next_sample = t0 + spec.sample_every
            for w, kind in _sample_windows(net, tracker.steps[T0], spec, rng):
                scene = tracker.scene(w, net.name, t0, disc=spec.disc)
                scene.meta["kind"] = kind
                scenes.append(scene)
                if progress is not None:
                    progress.update(1)
                if len(scenes) >= spec.scenes:
                    break
    return scenes


def record_at(net: Network, spec: EpisodeSpec, requests: list[tuple[float, Window]]) -> list[Scene]:
    """The episode of ``spec`` run again, each ``(time, window)`` of ``requests`` recorded at that
    simulation time (whole seconds): e.g. the windows of recorded scenes some time later, in the
    same traffic. A time the episode never reaches (its demand ran dry) gives an empty scene."""
    want = sorted(range(len(requests)), key=lambda i: requests[i][0])
    out: list[Scene | None] = [None] * len(requests)
    end = max((t for t, _ in requests), default=0.0)
    with _simulation(net, spec, extra_seconds=max(0.0, end - spec.begin - spec.warmup - spec.duration)) as traci:
        tracker = _Tracker(traci, net)
        k = 0
        while k < len(want):
            traci.simulationStep()
            tracker.step()
            t0 = traci.simulation.getTime() - 2.0
            if traci.simulation.getMinExpectedNumber() == 0:
                break
            while k < len(want) and len(tracker.steps) == len(TIMES) and requests[want[k]][0] <= t0 + 1e-6:
                t, w = requests[want[k]]
                out[want[k]] = tracker.scene(w, net.name, t0)
                k += 1
    return [s if s is not None else Scene.empty(w, net=net.name, time=t) for s, (t, w) in zip(out, requests)]


def _sample_windows(net: Network, state: dict, spec: EpisodeSpec, rng: np.random.Generator):
    ids = sorted(state)
    out = []
    for _ in range(spec.windows_per_sample):
        if ids and rng.random() < spec.p_ego:
            cx, cy, yaw = state[ids[rng.integers(len(ids))]][:3]
            out.append((Window(cx, cy, yaw, spec.window_size), KIND_EGO))
        else:
            xy, head = net.random_road_points(1, rng)
            out.append((Window(float(xy[0, 0]), float(xy[0, 1]), float(head[0]), spec.window_size),
                        KIND_ROAD))
    return out


def record_shard(net_path: str, spec: EpisodeSpec, net_index: int, shard_path: str) -> dict:
    """Record one episode into one shard file (a worker process's unit of work)."""
    scenes = record_episode(Network.load(net_path), spec)
    return write_shard(shard_path, scenes, net_index)


def record_shard_task(task: tuple) -> dict:
    """``record_shard(*task)``: the form a process pool's ``imap_unordered`` calls."""
    return record_shard(*task)


def plan_episodes(nets: list[Network], routes: list[str | None], begins: list[float],
                  scenes: int, seed: int, per_episode: int,
                  density: tuple[float, float] = DENSITY, disc: bool = True, default_sizes: float = 0.0,
                  peak_share: float = 0.0, peak_density: tuple[float, float] = PEAK_DENSITY
                  ) -> list[tuple[int, str, EpisodeSpec]]:
    """Deterministic episode plan: (net index, shard file name, spec) for every episode. A
    ``peak_share`` of the random-demand episodes draw their density log-uniformly from
    ``peak_density`` instead of ``density`` (peak-hour demand: queues at lights and junctions);
    ``default_sizes``: :attr:`EpisodeSpec.default_sizes`."""
    counts = [scenes // len(nets) + (i < scenes % len(nets)) for i in range(len(nets))]
    plan = []
    for k, (net, rou, begin, n) in enumerate(zip(nets, routes, begins, counts)):
        n_ep = max(1, -(-n // per_episode))
        for e in range(n_ep):
            ss = np.random.SeedSequence([seed, k, e])
            rng = np.random.default_rng(ss)
            ep_seed = int(ss.generate_state(1)[0] % (2 ** 31))
            todo = n // n_ep + (e < n % n_ep)
            spec = EpisodeSpec(seed=ep_seed, scenes=todo, routes=rou, begin=begin,
                               density=float(np.exp(rng.uniform(*np.log(density)))),
                               warmup=float(rng.uniform(200.0, 900.0)),
                               sample_every=float(rng.choice([2.0, 3.0, 5.0])), disc=disc,
                               default_sizes=default_sizes if rou is None else 0.0)
            # drawn after the others, and only when asked: plans without peaks stay as they were
            if peak_share and rng.random() < peak_share:
                spec = replace(spec, density=float(np.exp(rng.uniform(*np.log(peak_density)))))
            if todo > 0:
                plan.append((k, f"shard-{k:03d}-{e:04d}.npz", spec))
    return plan
