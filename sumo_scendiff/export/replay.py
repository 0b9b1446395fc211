"""What SUMO drives from a folder's start: its ``scenario.sumocfg`` (the saved state) run in libsumo
for the rollout's seconds, box-centre poses at every step, and each vehicle's type as SUMO has it.

A folder holds no FCD of its rollout, so the path is the one stock SUMO drives from the folder
(``sumo -c scenario.sumocfg``, the configuration's seed): what a user replaying the folder sees.

    with Replayer() as r:                      # one libsumo per network for many folders
        rep = r.replay(config, ids, seconds)

Starting SUMO is most of a folder's export on a city (loading its network), so a :class:`Replayer`
keeps SUMO running for the next folder of the same network and options and loads that folder's state
into it (``simulation.loadState``). A loaded state must drive as a fresh SUMO does, and two things of
the simulation it replaces outlive a load: the random number generators (a state file holds only how
many numbers each has drawn, and loading one draws forward, never back) and the lanes being simulated
(kept, in their order). So the lanes are let go first (a step without vehicles) and the state is loaded
with every generator as ``--seed`` sets it (the Mersenne Twister's seeding, written as SUMO's state
files write a generator past a million draws: ``default`` and the others the seed, lane generator i
the seed + i). Each SUMO is checked on its first folder against that folder replayed in a SUMO of its
own, and where they differ every folder of that network gets its own SUMO. Folders whose configuration
loads route or additional files (vehicles still to come, detectors and programs a state does not
reset), or asks for ``--random``, start SUMO of their own, as before (docs/openscenario.md, "Cost").
"""
from __future__ import annotations

import gzip
import os
import re
import tempfile
from dataclasses import dataclass, field
from functools import lru_cache

from ..core.geometry import sumo_to_pose
from ..sim.sumo import SimError, close, start_config
from .opendrive import ExportError

# options a folder's SUMO may differ by and still be the same SUMO: the state loaded and its seed
PER_FOLDER = frozenset({"load-state", "seed"})
# inputs whose content a state does not replace (its vehicles to come, its detectors and programs)
OWN_START = frozenset({"route-files", "additional-files", "r", "a"})
MT_N = 624                   # the Mersenne Twister's state words (std::mt19937)
FULL_STATE_DRAWS = 1000000   # SUMO's SAVE_ONLY_COUNT: a generator state past this many draws is written whole


@dataclass
class VehicleType:
    vclass: str
    length: float
    width: float
    height: float
    max_speed: float
    accel: float
    decel: float


@dataclass
class Replay:
    begin: float                                   # SUMO's time of the start (the scene's t = 0)
    step: float
    types: dict[str, VehicleType] = field(default_factory=dict)   # vehicle id -> its type
    # vehicle id -> [(t since the start, x, y, yaw, speed)], box centres
    paths: dict[str, list[tuple[float, float, float, float, float]]] = field(default_factory=dict)


def _type(sim, vid: str) -> VehicleType:
    t, vt = sim.vehicle.getTypeID(vid), sim.vehicletype
    return VehicleType(vt.getVehicleClass(t), vt.getLength(t), vt.getWidth(t), vt.getHeight(t),
                       min(vt.getMaxSpeed(t), sim.vehicle.getMaxSpeed(vid)), vt.getAccel(t), vt.getDecel(t))


def record(sim, ids: list[str], seconds: float) -> Replay:
    """``seconds`` of ``sim`` from where it stands, recording vehicles ``ids`` (those present)."""
    present = set(sim.vehicle.getIDList())
    want = [v for v in ids if v in present]
    out = Replay(begin=float(sim.simulation.getTime()), step=float(sim.simulation.getDeltaT()))
    out.types = {v: _type(sim, v) for v in want}
    out.paths = {v: [] for v in want}
    steps = int(round(seconds / out.step))
    for k in range(steps + 1):
        if k:
            sim.simulationStep()
        t = round(float(sim.simulation.getTime()) - out.begin, 6)
        here = set(sim.vehicle.getIDList())
        for v in want:
            if v in here:
                x, y = sim.vehicle.getPosition(v)
                cx, cy, yaw = sumo_to_pose(x, y, sim.vehicle.getAngle(v), out.types[v].length)
                out.paths[v].append((t, float(cx), float(cy), float(yaw), float(sim.vehicle.getSpeed(v))))
    return out


def _start(config: str, shared: bool = False):
    """SUMO on a folder; ``shared``: one whose state files list its generators (:func:`rng_layout`),
    for a folder without additional files (:func:`shared_key`), which start_config would quieten."""
    from ..sim.sumo import SILENT_OPTIONS, _start_libsumo, as_args
    try:
        if shared:
            return _start_libsumo(["-c", config, *as_args(SILENT_OPTIONS), "--save-state.rng", "true"])
        return start_config(config)
    except SimError as e:
        raise ExportError(f"{config}: {e}") from None


def replay(config: str, ids: list[str], seconds: float) -> Replay:
    """Run ``config`` for ``seconds`` in a SUMO of its own, recording vehicles ``ids`` (those present at the start)."""
    sim = _start(config)
    try:
        return record(sim, ids, seconds)
    finally:
        close(sim)


# ---- one SUMO for many folders ---------------------------------------------------------------------
def folder_options(config: str) -> dict[str, str]:
    from sumolib.options import readOptions
    return {o.name: o.value for o in readOptions(config)}


def shared_key(config: str) -> tuple | None:
    """What the folders one SUMO replays share: the network's content and every option but the state
    and the seed; None for a folder that starts SUMO of its own (module docstring)."""
    from ..core.files import file_sha256
    opts = folder_options(config)
    if OWN_START & set(opts) or opts.get("random") in ("true", "1") or not {"load-state", "seed", "net-file"} <= set(opts):
        return None
    net = os.path.join(os.path.dirname(os.path.abspath(config)), opts["net-file"])
    if not os.path.isfile(net):
        return None    # SUMO's own start says what is wrong
    return (file_sha256(net),) + tuple(sorted((k, v) for k, v in opts.items() if k not in PER_FOLDER | {"net-file"}))


@lru_cache(maxsize=256)
def seeded(seed: int) -> str:
    """A generator's state as ``std::mt19937::seed(seed)`` leaves it, as SUMO's state files write it."""
    x = [seed & 0xFFFFFFFF]
    for i in range(1, MT_N):
        x.append((1812433253 * (x[-1] ^ (x[-1] >> 30)) + i) & 0xFFFFFFFF)
    return f"{FULL_STATE_DRAWS} " + " ".join(map(str, x)) + f" {MT_N}"


def rng_layout(sim) -> tuple[list[str], int]:
    """(the names of SUMO's generators, the number of lane generators) as its state files list them."""
    fd, path = tempfile.mkstemp(suffix=".xml")
    os.close(fd)
    try:
        sim.simulation.saveState(path)
        with open(path) as f:
            text = f.read()
    finally:
        os.remove(path)
    head = re.search(r"<rngState([^>]*)>", text)
    return re.findall(r'(\S+)="', head.group(1)) if head else [], len(re.findall(r"<rngLane ", text))


def seeded_state(state: str, seed: int, layout: tuple[list[str], int]) -> str | None:
    """The text of state file ``state`` with every generator as ``seed`` sets it; None for a state
    holding generator states of its own (SUMO started from it restores those)."""
    opener = gzip.open if state.endswith(".gz") else open
    with opener(state, "rt", encoding="utf-8") as f:
        text = f.read()
    if "<rngState" in text or "<edgeControl" in text:
        return None
    names, lanes = layout
    block = "<rngState " + " ".join(f'{n}="{seeded(seed)}"' for n in names) + ">" + "".join(
        f'<rngLane index="{i}" state="{seeded(seed + i)}"/>' for i in range(lanes)) + "</rngState>"
    text, n = re.subn(r"(<snapshot\b[^>]*>)", lambda m: m.group(1) + block, text, count=1)
    return text if n else None


class Replayer:
    """Folders replayed one after another, in one SUMO while they share a network and options
    (module docstring); :meth:`close` (or the ``with`` block) ends it."""

    def __init__(self, share: bool = True):
        self.share = share    # False: every folder in a SUMO of its own (one folder: no second start to save)
        self.sim, self.key, self.layout = None, None, None
        self.untrusted: set[tuple] = set()    # keys whose loaded state drove otherwise than a fresh start

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        if self.sim is not None:
            close(self.sim)
        self.sim, self.key = None, None

    def replay(self, config: str, ids: list[str], seconds: float) -> Replay:
        """:func:`replay`'s record of ``config``, from the running SUMO where it can be."""
        key = shared_key(config) if self.share else None
        if key is not None and key == self.key:
            rep = self._loaded(config, ids, seconds)
            if rep is not None:
                return rep
        self.close()
        if key is None or key in self.untrusted:
            return replay(config, ids, seconds)
        self.sim = _start(config, shared=True)
        rep = record(self.sim, ids, seconds)    # started from the folder: what its own SUMO records
        self.layout = rng_layout(self.sim)
        # kept for the folders to come if the folder's state loaded into it drives the same
        if self._loaded(config, ids, seconds) == rep:
            self.key = key
        else:
            self.untrusted.add(key)
            self.close()
        return rep

    def _loaded(self, config: str, ids: list[str], seconds: float) -> Replay | None:
        """The record of ``config``'s state loaded into the running SUMO; None where it cannot be."""
        opts = folder_options(config)
        text = seeded_state(os.path.join(os.path.dirname(os.path.abspath(config)), opts["load-state"]),
                            int(opts["seed"]), self.layout)
        if text is None:
            return None
        fd, path = tempfile.mkstemp(suffix=".xml")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
            self._drain()
            self.sim.simulation.loadState(path)
        except Exception:   # libsumo.TraCIException: a state this SUMO does not take; a start of its own says why
            return None
        finally:
            os.remove(path)
        return record(self.sim, ids, seconds)

    def _drain(self) -> None:
        """No lane simulated, as in a SUMO just started: a load keeps the lanes SUMO was simulating, in
        their order, and takes up the state's other lanes after them (those of one random number
        generator then draw in another order); a step without vehicles lets every lane go."""
        for vid in self.sim.vehicle.getIDList():
            self.sim.vehicle.remove(vid)
        self.sim.simulationStep()
