"""A sweep worker: loads the model once, then runs tasks (scenarios that share a network and the
sampler settings, generated in one batched model call) and writes each scenario exactly as ``run``
does. One worker per process (libsumo allows one simulation per process); the local pool and the
Ray actors both wrap this class.
"""
from __future__ import annotations

import hashlib
import json
import os

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


class DensityUnsupported(ValueError):
    """A scenario asks for a traffic level the model cannot condition on."""


def scenario_target(s: Scenario, net, window, sim=None, checkpoint: str | None = None,
                    has_density: bool = True) -> float | None:
    """The scenario's density target (veh per km of car lane, vehicles already in the window
    included) from its ``density``/``vehicles``: ``"auto"`` is ``sim``'s own level around the window
    (the session's simulation of a network with routes) or, without one, None (the model's prior);
    neither given: as ``sim.density.default_density``.
    A target the model cannot take (``has_density`` False) raises :class:`DensityUnsupported`."""
    from ..sim.density import MODEL, default_density, host_has_traffic, window_target
    asked = s.density not in (None, MODEL) or s.vehicles is not None
    density = default_density(s.density, s.vehicles, host_has_traffic(sim), has_density)
    target = window_target(net, window, density, s.vehicles, sim=sim)
    if asked and target is not None and not has_density:
        what = f"density = {s.density!r}" if s.vehicles is None else f"vehicles = {s.vehicles}"
        if s.density == "auto":
            what += f" ({target:.1f} veh/km around the window)"
        raise DensityUnsupported(f"{what}: {checkpoint or 'the shipped model'} has no density condition "
                                 f"(trained before it); leave density/vehicles out of the spec or use a "
                                 f"newer --checkpoint")
    return target


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

    # ---- cached per network -------------------------------------------------------------------
    def network(self, entry: NetworkEntry):
        from ..map.network import Network
        if entry.name not in self._nets:
            self._nets[entry.name] = Network.load(entry.net)
        return self._nets[entry.name]

    def session(self, entry: NetworkEntry, step_length: float):
        from ..data.demand import demand_span, seeding_time
        from ..sim.session import Session
        from ..sim.sumo import SimConfig
        key = (entry.name, step_length)
        if key not in self._sessions:
            for old in self._sessions.values():   # one simulation per process: close the last one
                old.close()
            self._sessions.clear()
            routes = (entry.routes,) if entry.routes else ()
            net = self.network(entry)
            span = demand_span(routes, {ln.edge for ln in net.lanes}) if routes else None
            # SUMO starts at the first departure and runs the demand up to the seeding time
            at = seeding_time(entry.begin, None, span, routes, flag="begin") if span else None
            cfg = SimConfig(net=entry.net, routes=routes, step_length=step_length,
                            begin=span[0] if span else entry.begin)
            warm = (lambda sim: [sim.simulationStep() for _ in
                                 range(int(round((at - sim.simulation.getTime()) / step_length)))]) \
                if routes else None
            self._sessions[key] = Session(cfg, net, self.generator).prepare(warm)
        return self._sessions[key]

    def window(self, entry: NetworkEntry, location: str):
        from ..map.locations import auto_windows, window_at
        net = self.network(entry)
        if location.startswith("auto:"):
            if entry.name not in self._auto:   # the same n in every worker: the same windows
                self._auto[entry.name] = auto_windows(net, self.spec.auto_count(), seed=0)
            loc = self._auto[entry.name][int(location[5:])]
            return loc.window, loc.kind
        x, y, *yaw = (float(v) for v in location.split(","))
        return window_at(net, x, y, yaw[0] if yaw else 0.0), "center"

    # ---- one task -----------------------------------------------------------------------------
    def run(self, scenarios: list[Scenario], done: frozenset[str] = frozenset()) -> list[str]:
        """Run scenarios that share network, step length and sampler settings; returns the ids run.
        A scenario whose network, location or tokens fail is recorded as failed, the rest go on.

        Scenarios in ``done`` (finished before a resume) are generated again but not written: the
        model call then sees the same batch as in an uninterrupted sweep, and float results depend
        on the batch (the classifier-free guidance amplifies that noise)."""
        from ..data.demand import DemandError
        from ..map.locations import LocationError
        from ..map.network import NetworkError
        from ..sim.lights import light_states
        from ..sim.sumo import SimError
        from ..tokens.file import TokenFileError
        bad = (NetworkError, LocationError, TokenFileError, SimError, DemandError, OSError)
        # a batch run again after its worker died (core.pool) keeps what that worker completed
        done = frozenset(done) | {s.id for s in scenarios if os.path.isdir(os.path.join(self.out, s.id))}
        first = scenarios[0]
        entry = self.spec.networks[first.network]
        try:
            session = self.session(entry, first.step_length)
        except bad as e:
            todo = [s for s in scenarios if s.id not in done]
            for s in todo:
                write_failure(self.out, s, str(e))
            return [s.id for s in todo]
        ready = []
        for s in scenarios:
            try:
                window, kind = self.window(entry, s.location)
                spec_tokens = self.spec.token_sets[s.token_set]
                user = spec_tokens.for_window(window)
                existing = session.existing(window)
                tokens = user + existing.tokens()
                sources = ["user"] * len(user) + existing.token_ids()
                p_mask = s.p_mask if s.p_mask is not None else spec_tokens.p_mask
                # after existing(): the session's simulation is at the seeding time
                target = scenario_target(s, session.net, window, session.sim if entry.routes else None,
                                         self.checkpoint, self.generator.has_density)
                lights = light_states(session.sim, session.net.lights_in(window)) \
                    if first.generation.signals else None   # as the scene meets them
                ready.append((s, window, kind, tokens, sources, existing, p_mask, target, lights))
            except bad + (DensityUnsupported,) as e:
                if s.id not in done:
                    write_failure(self.out, s, str(e))
        if ready:
            cfg = first.generation
            targets = [r[7] for r in ready]
            scenes = self.generator.generate(session.net, [r[1] for r in ready], tokens=[r[3] for r in ready],
                                             p_mask=[r[6] for r in ready], config=cfg,
                                             noise_seeds=[noise_seed(r[0]) for r in ready],
                                             density=targets if any(d is not None for d in targets) else None,
                                             signals=[r[8] for r in ready])
            for (s, window, kind, tokens, sources, existing, p_mask, target, _), scene in zip(ready, scenes):
                if s.id in done:
                    continue
                info = {"scene": s.id, "location": kind, "sweep": {**s.params(), "kind": kind,
                                                                    "p_mask_used": p_mask,
                                                                    "density_target_veh_per_km": target,
                                                                    "car_lane_km": round(
                                                                        session.net.car_lane_km(window), 4)},
                        "model": cfg.record(self.generator),
                        "sumo_options": session.cfg.options()}
                try:
                    session.realise(scene, tokens, sources, existing, self.out, s.id, info, s.rollout,
                                    seed=s.seed, p_mask=p_mask, replay=s.replay)
                except bad as e:
                    write_failure(self.out, s, str(e), density_target_veh_per_km=target)
        return [s.id for s in scenarios if s.id not in done]

    def close(self) -> None:
        for s in self._sessions.values():
            s.close()
        self._sessions.clear()
