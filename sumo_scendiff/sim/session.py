"""One network, many scenes: the per-scene pipeline shared by ``run`` and ``sweep``.

    session = Session(SimConfig(net=path), net, generator)      # warm-up demand once if -r given
    session.prepare(warm_up)                                    # base state (after the warm-up)
    existing = session.existing(window)                         # vehicles there -> tokens
    row = session.realise(scene, tokens, sources, existing, out_dir, "scene_000", info, rollout=60)

Every scene runs in a freshly started SUMO (that loads the base state when there is demand), so a
scene's rollout never depends on which scenes came before it (SUMO's random streams are not part of
a saved state: reusing one simulation made the same scene drive differently after different
predecessors, measured). The state is loaded as SUMO starts (``--load-state``), not by
``simulation.loadState`` after it, which inserts a finished flow's first vehicle again
(``SimConfig.state``). Without demand the rollout is exactly reproducible for a seed. With demand,
libsumo 1.28 continuing from a loaded state made the following steps depend on where SUMO's objects
lie in memory (measured with ``loadState`` by ``benchmarks/seeding.py``, which runs SUMO without
address randomisation to compare methods), so those rollouts can differ slightly between runs; the
generated scenes do not.
"""
from __future__ import annotations

import os
import tempfile
import time
from contextlib import contextmanager
from dataclasses import replace

from .cosim import CoSimulation, Existing
from .export import ScenarioWriter
from .fleet import Fleet
from .rollout import rollout
from .state import save_state
from .sumo import SimConfig, SimError, close, died, start


def _stopped(e: BaseException, sim=None) -> BaseException:
    """SUMO stopping on the demand (an unknown vType, a route with no connection) as a SimError of one
    line, SUMO's process ending meanwhile (traci ``sim``) as SumoDied; any other exception as it is."""
    gone = died(e, sim) if sim is not None else None
    if gone is not None:
        return gone
    if type(e).__name__ not in ("TraCIException", "FatalTraCIError"):
        return e
    msg = str(e).strip().splitlines()
    return SimError(f"SUMO stopped while running the demand: {msg[-1] if msg else type(e).__name__}")


class Session:
    def __init__(self, cfg: SimConfig, net, generator, quiet: bool = True, model_fleet: bool = False):
        self.cfg, self.net, self.generator, self.quiet = cfg, net, generator, quiet
        self.model_fleet = model_fleet   # the model's sizes on SUMO's default vType (run --model-fleet)
        self.base: str | None = None
        self._owns_base = True           # a base state this session saved (removed at close)
        self.sim = None
        self._at_base = False
        self._base_draws = False         # the base state holds SUMO's random numbers (prepare_at)
        self.timing = {"seed": 0.0, "export": 0.0, "rollout": 0.0}

    # ---- the base simulation --------------------------------------------------------------------
    def prepare(self, warm_up=None, state: str | None = None) -> "Session":
        """Start SUMO, run ``warm_up(sim)`` (the demand up to the seeding time) if given, and keep
        the state as the base of every scene; or start from ``state``, a saved state that is the
        base as it is (sim/warmup.py's, kept by its cache: never removed here). The simulation stays
        open for :meth:`existing`."""
        if state is not None:
            self.sim = start(replace(self.cfg, state=state), quiet=self.quiet)
            self._at_base, self.base, self._owns_base = True, state, False
            return self
        if warm_up is None:
            self.sim = start(self.cfg, quiet=self.quiet)
            self._at_base = True
            return self
        # the demand runs as the user's own sumo runs it (warmup.warm_config: their options alone, SUMO's
        # draws kept in the state), headless as prepare_at's; the scenes then start from its state
        from .warmup import warm_config
        sim = start(replace(warm_config(self.cfg), gui=False, traci=False), quiet=self.quiet)
        try:
            with self._said():
                warm_up(sim)
            fd, base = tempfile.mkstemp(suffix=".xml.gz", prefix="scendiff-base-")
            os.close(fd)
            save_state(sim, base)
        except Exception as e:   # SUMO stopping on the demand (an unknown vType, a broken route)
            raise _stopped(e, sim) from None
        finally:
            close(sim)
        self.prepare(state=base)
        self._owns_base, self._base_draws = True, True
        return self

    def prepare_at(self, until: float) -> "Session":
        """:meth:`prepare` with the demand run to ``until`` as stock SUMO runs it (sim/warmup.py: one
        ``simulationStep(until)``, the state kept and reused when the same scenario and time are
        asked again) and SUMO started from that state. Raises warmup.WarmUpError for a time before
        the start, SimError when SUMO stops on the demand."""
        from .warmup import warm_state
        t = time.perf_counter()
        try:
            with self._said():
                state = warm_state(replace(self.cfg, gui=False, traci=False), until, quiet=self.quiet)
        except Exception as e:   # SUMO stopping on the demand (an unknown vType, a broken route)
            raise _stopped(e) from None
        self.timing["warm_up"] = time.perf_counter() - t   # a part of the caller's load (0 when reused)
        self.prepare(state=state)
        self._base_draws = True          # warm_config saves SUMO's random numbers' counts with the state
        return self

    def at_base(self):
        """The simulation at the base state (restarted if a scene has run since)."""
        if not self._at_base:
            if self.sim is not None:
                close(self.sim)
            self.sim = start(replace(self.cfg, state=self.base), quiet=self.quiet)
            self._at_base = True
        return self.sim

    def cosim(self, seed: int = 0) -> CoSimulation:
        return CoSimulation(self.at_base(), self.net, self.generator, seed=seed)

    def existing(self, window) -> Existing:
        return self.cosim().existing(window)

    def close(self) -> None:
        if self.sim is not None:
            close(self.sim)
            self.sim = None
        if self.base and self._owns_base:
            os.remove(self.base)
        self.base = None

    @contextmanager
    def _said(self):
        """With warnings on (-v), what SUMO says while it steps (a warning per vehicle: no
        connection, an emergency brake, a teleport) shown after the block, each kind once with its
        count (core.sumo_log), as the fill shows its own. sumo-gui is a process of its own, its
        console its own."""
        if self.quiet or self.cfg.gui:
            yield
            return
        from ..core.sumo_log import caught_stderr, echo
        with caught_stderr() as said:
            try:
                yield
            finally:
                echo(said())

    # ---- one scene ----------------------------------------------------------------------------
    def realise(self, *args, **kwargs) -> dict:
        """:meth:`_realise`, what SUMO says meanwhile summarised (:meth:`_said`)."""
        with self._said():
            return self._realise(*args, **kwargs)

    def _realise(self, scene, tokens: list[dict], sources: list[str], existing: Existing, out_dir: str,
                name: str, info: dict, rollout_s: float, seed: int = 0, p_mask: float = 1.0,
                force: bool = False, progress: bool = False, replay: float = 0.0) -> dict:
        """Seed ``scene`` into a fresh simulation at the base state, export it to
        ``out_dir/name``, hold the agents on their generated future for ``replay`` seconds (<= 2)
        and roll it out; returns the row of statistics (also in rollout.json)."""
        # a base state holding SUMO's random numbers (the demand's run to T) goes on under the seed it
        # was run with: SUMO saves how far each generator has drawn and, loading it, draws that far
        # from --seed; so the demand goes on after T as the user's own run does, whatever -s is
        sumo_seed = self.cfg.seed if self._base_draws else seed
        # the simulation still at the base with this seed serves the scene as a fresh one would (the
        # first scene of a run: SUMO started once, not twice)
        reuse = self._at_base and self.sim is not None and sumo_seed == self.cfg.seed
        if self.sim is not None and not reuse:
            close(self.sim)
            self.sim = None
        self._at_base = False
        writer = ScenarioWriter(out_dir, name, force=force)
        try:
            t = time.perf_counter()
            sim = self.sim if reuse else start(replace(self.cfg, seed=sumo_seed, state=self.base), quiet=self.quiet)
            self.sim = sim
            cosim = CoSimulation(sim, self.net, self.generator, seed=seed, prefix="sd")
            if self.model_fleet:   # a fleet without a mix: no drawn agent is given a scenario's vType
                cosim.seeder.fleet = Fleet(sim, {})
            seeding = cosim.place(scene, tokens, sources, existing, seed=seed, p_mask=p_mask)
            sim.simulationStep()
            cosim.verify(seeding, warn=False)      # run prints them, once per scene (user_tokens_lost)
            self.timing["seed"] += time.perf_counter() - t
            t = time.perf_counter()
            writer.after_seeding(sim, seeding, self.net, self.cfg.options(), info)
            self.timing["export"] += time.perf_counter() - t
            t = time.perf_counter()
            if replay > 0:
                cosim.replay_future(seeding, replay)
            stats = rollout(sim, seeding.agent_ids, rollout_s, progress=progress)
            self.timing["rollout"] += time.perf_counter() - t
            t = time.perf_counter()
            rep = seeding.report
            user = [k for k, (src, tok) in enumerate(zip(sources, tokens))
                    if src == "user" and tok.get("x") is not None]
            lost = seeding.lost_tokens()
            row = {"user_tokens": len(user),
                   "user_tokens_matched": len(set(user) & set(t for t in seeding.token_of if t is not None)),
                   # every user token that gives no vehicle, with why (run prints them as warnings)
                   "user_tokens_lost": {str(k): why for k, why in sorted(lost.items())},
                   **seeding.counts(), "slowed": len(rep.slowed), "gap_fitted": len(rep.gap_fitted),
                   "existing_vehicles": len(existing.token_ids()),
                   "dropped_on_existing": seeding.dropped, "replayed_s": replay, **stats.as_dict()}
            writer.finish(row)
            self.timing["export"] += time.perf_counter() - t
            return row
        except BaseException as e:
            writer.abandon()
            raise _stopped(e, self.sim) from None
