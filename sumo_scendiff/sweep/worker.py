"""A sweep worker: loads the model once, then runs tasks (scenarios that share a network and the
sampler settings, generated in one batched model call) and writes each scenario exactly as ``run``
does. One worker per process (libsumo allows one simulation per process); the local pool and the
Ray actors both wrap this class.
"""
from __future__ import annotations

import hashlib
import json
import os

from ..sim.request import DensityUnsupported, density_target
from .spec import NetworkEntry, Scenario, Spec


def noise_seed(s: Scenario) -> int:
    """The initial-noise seed: network, location and seed only, so the variants of a token set or
    p_mask start from the same noise (like the paper's Fig. 4 variants)."""
    key = f"{s.network}|{s.location}|{s.seed}".encode()
    return int.from_bytes(hashlib.sha256(key).digest()[:4], "little")


def failure_path(out: str, sid: str) -> str:
    return os.path.join(out, f"{sid}.failed.json")


def write_failure(out: str, s: Scenario, error: str, **extra) -> None:
    tmp = failure_path(out, s.id) + ".partial"
    with open(tmp, "w") as f:
        json.dump({**s.params(), **extra, "status": "failed", "error": error}, f)
    os.replace(tmp, failure_path(out, s.id))


def _unsupported(s: Scenario, target: float, checkpoint: str | None) -> str:
    """The failure of a scenario asking a traffic level of a model without the density condition."""
    what = f"density = {s.density!r}" if s.vehicles is None else f"vehicles = {s.vehicles}"
    if s.density == "auto":
        what += f" ({target:.1f} veh/km around the window)"
    return (f"{what}: {checkpoint or 'the shipped model'} has no density condition (trained before it); "
            f"leave density/vehicles out of the spec or use a newer --checkpoint")


def scenario_target(s: Scenario, net, window, sim=None, checkpoint: str | None = None,
                    has_density: bool = True) -> float | None:
    """The scenario's density target (``sim.request.density_target`` of its ``density``/``vehicles``;
    ``sim``: the session's simulation where the network has routes). A target the model cannot take
    (``has_density`` False) raises :class:`DensityUnsupported` naming the spec's key."""
    try:
        return density_target(net, window, s.density, s.vehicles, sim=sim, has_density=has_density)
    except DensityUnsupported as e:
        raise DensityUnsupported(e.target, _unsupported(s, e.target, checkpoint)) from None


class Worker:
    def __init__(self, spec: Spec, out: str, checkpoint: str | None = None, threads: int | None = None,
                 generator=None):
        from ..core.threads import GENERATION_THREADS, share_cpu
        share_cpu(threads, default=GENERATION_THREADS)   # before torch is imported (core/threads.py: why one)
        from ..generation.generator import ScenarioGenerator
        self.spec, self.out, self.checkpoint = spec, out, checkpoint
        # ``generator``: an already loaded one (tests); else the checkpoint's
        self.generator = generator if generator is not None else ScenarioGenerator.load(checkpoint)
        self._nets: dict[str, object] = {}
        self._sessions: dict[tuple, object] = {}
        self._auto: dict[str, list] = {}
        self._demand: dict[str, list[str]] = {}

    # ---- cached per network -------------------------------------------------------------------
    def network(self, entry: NetworkEntry):
        from ..map.network import Network
        if entry.name not in self._nets:
            self._nets[entry.name] = Network.load(self.spec.scenario_of(entry.name).net)
        return self._nets[entry.name]

    def demand(self, entry: NetworkEntry) -> list[str]:
        """The files holding the entry's demand (``data.demand.demand_files``: its route files, and
        additional files with vehicles in them, as run reads them)."""
        from ..data.demand import demand_files
        if entry.name not in self._demand:
            scen = self.spec.scenario_of(entry.name)
            self._demand[entry.name] = demand_files(scen.routes, scen.additional)
        return self._demand[entry.name]

    def _times(self, entry: NetworkEntry, scen, net) -> tuple[float | None, float | None]:
        """(the time SUMO starts at, the seeding time it runs the demand up to; None: no demand), as
        run takes them: SUMO starts at the configuration's begin, else the demand's first departure,
        and runs it to the entry's ``begin`` (default: that start + the warm-up)."""
        from ..data.demand import start_times
        demand = self.demand(entry)
        if not demand:
            return (entry.begin if entry.begin is not None else scen.begin), None
        start, at, _ = start_times(scen, {ln.edge for ln in net.lanes}, entry.begin, demand, flag="begin")
        return start, at

    def session(self, entry: NetworkEntry, step_length: float):
        from ..sim.scenario import own_random
        from ..sim.session import Session
        from ..sim.sumo import SimConfig
        key = (entry.name, step_length)
        if key not in self._sessions:
            for old in self._sessions.values():   # one simulation per process: close the last one
                old.close()
            self._sessions.clear()
            scen, net = self.spec.scenario_of(entry.name), self.network(entry)
            begin, at = self._times(entry, scen, net)
            # the user's scenario as run starts it: its additional files (vTypes, programs, stops),
            # its options; the step is the scenario's (spec.Spec.step_length_of) unless the spec's
            # and its demand run with its own SUMO seed (run's _session)
            seed, rng = own_random(scen) if at is not None else (0, ())
            cfg = SimConfig(net=scen.net, routes=scen.routes, additional=scen.additional, seed=seed, extra=rng,
                            step_length=step_length, begin=begin, scenario_options=scen.options)
            session = Session(cfg, net, self.generator)
            # the demand run to the seeding time as stock SUMO runs it, its state kept (sim/warmup.py)
            self._sessions[key] = session.prepare_at(at) if at is not None else session.prepare()
        return self._sessions[key]

    def window(self, entry: NetworkEntry, location: str, session=None):
        """(window, kind of place) of a scenario's location; ``session``: the entry's, whose base state
        places the automatic windows where the demand has vehicles (None: a centre, or no demand)."""
        from ..map.locations import auto_windows, window_at
        net = self.network(entry)
        if location.startswith("auto:"):
            if entry.name not in self._auto:   # the same n and base state in every worker: the same windows
                self._auto[entry.name] = auto_windows(net, self.spec.auto_count(), seed=0,
                                                      traffic=self._traffic(entry, session))
            loc = self._auto[entry.name][int(location[5:])]
            return loc.window, loc.kind
        x, y, *yaw = (float(v) for v in location.split(","))
        return window_at(net, x, y, yaw[0] if yaw else 0.0), "center"

    def _traffic(self, entry: NetworkEntry, session) -> list | None:
        """Where the entry's demand has vehicles at the seeding time (front bumpers), as run's automatic
        windows take them; None without a demand (the layout alone). Read from the base state, which
        every worker loads alike (an entry's scenarios share one step length: Spec.scenarios)."""
        if session is None or not self.demand(entry):
            return None
        from ..sim.density import host_positions
        return host_positions(session.at_base())

    # ---- one task -----------------------------------------------------------------------------
    @staticmethod
    def _failures() -> tuple[type, ...]:
        """The errors that fail one scenario (recorded in its .failed.json), not the sweep."""
        from ..data.demand import DemandError
        from ..map.locations import LocationError
        from ..map.network import NetworkError
        from ..sim.sumo import SimError
        from ..tokens.file import TokenFileError
        return (NetworkError, LocationError, TokenFileError, SimError, DemandError, OSError)

    def run(self, scenarios: list[Scenario], done: frozenset[str] = frozenset()) -> list[str]:
        """Run scenarios that share network, step length and sampler settings; returns the ids run.
        A scenario whose network, location or tokens fail is recorded as failed, the rest go on.

        Scenarios in ``done`` (finished before a resume) are generated again but not written: the
        model call then sees the same batch as in an uninterrupted sweep, and float results depend
        on the batch (the classifier-free guidance amplifies that noise)."""
        # a batch run again after its worker died (core.pool) keeps what that worker completed
        done = frozenset(done) | {s.id for s in scenarios if os.path.isdir(os.path.join(self.out, s.id))}
        entry = self.spec.networks[scenarios[0].network]
        try:
            session = self.session(entry, scenarios[0].step_length)
        except self._failures() as e:
            todo = [s for s in scenarios if s.id not in done]
            for s in todo:
                write_failure(self.out, s, str(e))
            return [s.id for s in todo]
        ready = self._requests(scenarios, entry, session, done)
        if ready:
            self._generate_and_write(ready, session, done)
        return [s.id for s in scenarios if s.id not in done]

    def _requests(self, scenarios: list[Scenario], entry: NetworkEntry, session, done) -> list[tuple]:
        """(scenario, kind of place, its window's request: sim/request.py) of each scenario that
        has one; a scenario that fails here is recorded as failed."""
        from ..sim.fleet import Fleet
        from ..sim.request import window_request
        fleet = Fleet.read(session.sim)    # a token's vtype: one of the scenario's, its size
        out = []
        for s in scenarios:
            try:
                window, kind = self.window(entry, s.location, session)
                token_set = self.spec.token_sets[s.token_set]
                # session.existing(): the session's simulation at the seeding time
                req = window_request(session.net, session.sim, window, session.existing(window),
                                     token_set.for_window(window), source=token_set.source, fleet=fleet,
                                     p_mask=s.p_mask if s.p_mask is not None else token_set.asked_p_mask(),
                                     density=s.density, vehicles=s.vehicles, host=bool(self.demand(entry)),
                                     has_density=self.generator.has_density, signals=s.generation.signals)
                out.append((s, kind, req))
            except DensityUnsupported as e:
                if s.id not in done:
                    write_failure(self.out, s, _unsupported(s, e.target, self.checkpoint))
            except self._failures() as e:
                if s.id not in done:
                    write_failure(self.out, s, str(e))
        return out

    def _generate_and_write(self, ready: list[tuple], session, done) -> None:
        """The scenes of ``ready`` in one model call, each written as ``run`` writes a scene."""
        from ..sim.request import generation_inputs
        cfg = ready[0][0].generation
        requests = [req for _, _, req in ready]
        scenes = self.generator.generate(session.net, [r.window for r in requests], config=cfg,
                                         noise_seeds=[noise_seed(s) for s, _, _ in ready],
                                         **generation_inputs(requests))
        for (s, kind, req), scene in zip(ready, scenes):
            if s.id in done:
                continue
            info = {"scene": s.id, "location": kind,
                    "sweep": {**s.params(), "kind": kind, "p_mask_used": req.p_mask,
                              "density_target_veh_per_km": req.target,
                              "car_lane_km": round(session.net.car_lane_km(req.window), 4)},
                    "model": cfg.record(self.generator), "sumo_options": session.cfg.options()}
            try:
                session.realise(scene, req.tokens, req.sources, req.existing, self.out, s.id, info, s.rollout,
                                seed=s.seed, p_mask=req.p_mask, replay=s.replay)
            except self._failures() as e:
                write_failure(self.out, s, str(e), density_target_veh_per_km=req.target)

    def close(self) -> None:
        for s in self._sessions.values():
            s.close()
        self._sessions.clear()
