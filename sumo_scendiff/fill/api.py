"""The fill as a library call: a whole network filled with generated traffic, a folder SUMO starts from.

    from sumo_scendiff.fill.api import fill
    f = fill("city.net.xml", 25, out="filled")                       # 25 veh per km of car lane
    f = fill(config="scenario.sumocfg", begin=28800, out="filled")   # the demand's own level
    f.summary["vehicles"], f.folder                                  # fill.json's summary, the folder

``amount``: a number (vehicles per km of car lane), an edgeData file (each tile's density at
``begin``), or None (with a demand: its vehicles en route at ``begin``; without: the model's prior
scaled by ``p_mask``). The folder is written under ``out.partial-<pid>`` and takes its name only when
complete; bad input raises :class:`FillError` (one line), nothing left behind. The CLI
(``python -m sumo_scendiff.fill``) is this call with flags (docs/fill.md).
"""
from __future__ import annotations

import os
import shutil
import sys
import time
from dataclasses import dataclass, field

from .workers import default_workers


class FillError(Exception):
    """A problem with the user's input (the CLI: exit code 2, one line)."""


class Interrupted(KeyboardInterrupt):
    """The fill was stopped; ``complete``: the folder had its name already (it is kept)."""

    def __init__(self, complete: bool):
        super().__init__()
        self.complete = complete


@dataclass(frozen=True)
class FillRequest:
    """Everything a fill depends on (the CLI's flags, the library call's arguments)."""
    net: str | None = None
    config: str | None = None
    routes: tuple[str, ...] = ()
    additional: tuple[str, ...] = ()
    begin: float | None = None
    area: tuple | None = None
    stride: float = 75.0
    density: float | None = None
    edge_data: str | None = None
    demand_level_only: bool = False
    p_mask: float = 1.0
    seed: int = 0
    step_length: float | None = None
    lateral_resolution: float | None = None
    seeding_options: bool = True
    model_fleet: bool = False
    checkpoint: str | None = None
    workers: int | None = None           # None: one per core (fill.workers.default_workers)
    ray_address: str | None = None
    export: str | None = None
    verbose: bool = False
    generation: object | None = None     # a GenerationConfig (None: the defaults)
    progress: bool = False
    # with a demand and no other level: the model's fill from the demand estimate (fill/demand.py)
    # instead of SUMO's own run of the scenario to begin (fill/warm_start.py)
    demand_estimate: bool = False

    @property
    def sumo_start(self) -> bool:
        """Whether the start is SUMO's own run of the demand (given one: fill/warm_start.py); with an
        area, what that run has inside it."""
        return not (self.demand_estimate or self.density is not None or self.edge_data
                    or self.demand_level_only)


@dataclass
class Fill:
    """A written fill: its folder and fill.json."""
    folder: str
    doc: dict = field(repr=False)

    @property
    def summary(self) -> dict:
        return self.doc["summary"]


def fill(network: str | None = None, amount=None, area: tuple | None = None, *, out: str = "filled",
         force: bool = False, **settings) -> Fill:
    """Fill ``network`` (or ``config=`` a .sumocfg) with ``amount`` inside ``area`` (X0, Y0, X1, Y1;
    None: every car lane) and write the folder ``out`` (``force``: replace one there). ``settings``:
    the fields of :class:`FillRequest` (routes, additional, begin, seed, stride, p_mask, workers, ...)."""
    if amount is not None and not isinstance(amount, (int, float)):
        settings["edge_data"] = os.fspath(amount)
    elif amount is not None:
        settings["density"] = float(amount)
    return fill_request(FillRequest(net=network, area=area, **settings), out, force)


def fill_request(req: FillRequest, out: str, force: bool = False) -> Fill:
    """The fill of ``req`` written to ``out``: under a partial name until complete, then renamed
    (an existing ``out`` only with ``force``); raises FillError / the layers' input errors, or
    :class:`Interrupted` (the partial folder removed)."""
    from ..core.outputs import claim, clean_stale, partial_path
    path = os.path.abspath(out.rstrip("/") or out)
    _check_out(path, out, force)
    clean_stale(os.path.dirname(path), {os.path.basename(path)})   # what dead runs left half-written
    owner, complete = None, False
    try:
        with claim(partial_path(path)) as owner:
            doc = fill_into(req, owner.directory)
            if os.path.lexists(path):
                if not force and (not os.path.isdir(path) or os.listdir(path)):
                    raise FillError(f"-o: {out}: was written by another run meanwhile")
                shutil.rmtree(path) if os.path.isdir(path) else os.remove(path)
            owner.rename(path)   # complete: only now the folder has its name
            complete = True
            if req.export and not doc.get("nothing_to_generate"):
                from ..export.batch import export_after
                export_after(os.path.dirname(path), [os.path.basename(path)], req.export)
    except KeyboardInterrupt:
        _abandon(owner)
        raise Interrupted(complete) from None
    except BaseException:
        _abandon(owner)
        raise
    return Fill(path, doc)


def _check_out(path: str, out: str, force: bool) -> None:
    if os.path.exists(path) and not force and (not os.path.isdir(path) or os.listdir(path)):
        raise FillError(f"-o: {out}: exists (choose another output directory or add --force)")
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
    except OSError as e:
        up = next((d for d in _parents(path) if os.path.exists(d) and not os.path.isdir(d)), None)
        raise FillError(f"-o: {out}: " + (f"{up} is a file, not a folder" if up else
                                          f"its folder cannot be created ({e.strerror or e})")) from None


def _parents(path: str):
    while os.path.dirname(path) != path:
        path = os.path.dirname(path)
        yield path


def _abandon(owner) -> None:
    """An unfinished fill leaves nothing behind that could be taken for one."""
    if owner is not None and os.path.basename(owner.directory).count(".partial-"):
        shutil.rmtree(owner.directory, ignore_errors=True)


def phase(progress: bool, text: str) -> None:
    """One line on stderr as a phase without a progress bar of its own begins (with progress)."""
    if progress:
        print(f"fill: {text} ...", file=sys.stderr, flush=True)


def fill_into(req: FillRequest, folder: str) -> dict:
    """The fill of ``req`` written into ``folder``; returns fill.json's document."""
    from ..sim.lights import light_states
    from .plan import fill_network
    from .workers import tile_engine
    t = time.perf_counter()
    prep = prepare(req, folder)
    if isinstance(prep, dict):          # nothing to fill: fill.json says why
        return prep
    net, gen, scen, tiles, begin, demand = prep
    from dataclasses import replace
    from .tiles import whole_area
    req = replace(req, area=whole_area(net, req.area))    # as the tiles were laid (tiles.whole_area)
    if gen is None:     # SUMO's own start: no model
        from .warm_start import sumo_start
        return sumo_start(req, net, scen, begin[0], begin[1], folder, {"load": time.perf_counter() - t})
    begin = begin[0]
    workers = req.workers or default_workers()
    cfg = _sim_config(req, scen, begin)
    from .output import seeding_sumo, write_outputs
    # one SUMO for the fill: the lights' states at the start read from it, the tiles seeded into it
    with seeding_sumo(cfg, list(scen.routes), quiet=not req.verbose, demand=demand) as sumo:
        # started here, the workers load their model while this process prepares the rest
        with tile_engine(net, gen, workers, req.ray_address, req.checkpoint) as engine:
            amount = plan_amount(req, net, gen, tiles, scen, begin, demand)
            timing = {"load": time.perf_counter() - t}
            signals = light_states(sumo[0]) if net.signal_links and gen.config.signals else None
            t = time.perf_counter()
            result = fill_network(net, gen, tiles, seed=req.seed, p_mask=req.p_mask, targets=amount.targets,
                                  use_density=amount.applied, area=req.area, progress=req.progress,
                                  signals=signals, engine=engine, demand=amount.placed)
            timing["generate"] = time.perf_counter() - t
        record = {"count": workers, "engine": "ray" if req.ray_address is not None else "local",
                  "ray_address": req.ray_address,
                  "note": "the fill does not depend on the workers: each tile's noise is its own and the "
                          "model calls are cut from the plan alone"}
        phase(req.progress, "seeding the tiles into SUMO, then writing the state and the portable start (each "
                            "loaded once in SUMO)" + ("" if demand else " and the inflow (the filled "
                                                                       "network driven on to measure it)"))
        return write_outputs(folder, req, net, gen, scen, demand, cfg, sumo, result, amount.source,
                             timing, req.progress, record)


def prepare(req: FillRequest, folder: str):
    """The inputs judged and loaded: (network, generator, scenario, tiles, (begin, SUMO's start), the
    files holding its demand), the generator and tiles None where SUMO's own run makes the start; or
    fill.json's document where the scenario has no car lane."""
    from dataclasses import replace

    from ..sim.preflight import preflight
    from ..sim.scenario import ScenarioError, scenario_from_files
    try:   # the user's inputs judged by SUMO itself before the model is even imported
        scen = preflight(scenario_from_files(req.config, req.net, list(req.routes), list(req.additional)))
    except ScenarioError as e:
        raise FillError(str(e)) from None
    from ..map.network import Network, NoCarLane
    phase(req.progress, f"loading {os.path.basename(scen.net)}")
    try:
        net = Network.load(scen.net)
    except NoCarLane as e:
        if not req.config:     # a bare -n: the user chose a network the model cannot use
            raise
        return _nothing_to_fill(folder, req, scen, f"no car lane: {e}")
    from ..data.demand import demand_files
    # route files and additional files holding vehicles (SUMO's games keep their traffic in one)
    demand = tuple(demand_files(scen.routes, scen.additional))
    if req.demand_level_only and not demand:
        raise FillError("--demand-level-only: there is no demand (give -r, or -c with route files or "
                        "additional files holding vehicles)")
    begin = _begin(req, net, scen, demand)
    if demand and req.sumo_start:
        _area_has_road(req, net)
        return net, None, scen, None, begin, demand       # SUMO's own run: no model, no torch
    tiles = _tiles(req, net)
    from ..core.threads import GENERATION_THREADS, share_cpu
    share_cpu(default=GENERATION_THREADS)   # before torch is imported (core/threads.py: why one)
    from ..generation.generator import GenerationConfig, ScenarioGenerator
    phase(req.progress, "loading the model")
    # a density asked in veh/km (or read from edgeData) is kept as SUMO's edgeData counts it; a
    # demand's vehicles are counted one by one. A tile's pins are its neighbours' vehicles in the
    # overlap, context the tile does not keep (only its core's agents are), so their speeds are not
    # calibrated (generation/pinning.py): the same counts and hold for a third less CPU (docs/fill.md)
    gen_cfg = replace(req.generation or GenerationConfig(), pin_calibration=False,
                      count_on_edges=req.density is not None or bool(req.edge_data))
    return net, ScenarioGenerator.load(req.checkpoint, gen_cfg), scen, tiles, begin, demand


def _begin(req: FillRequest, net, scen, demand: tuple[str, ...]) -> tuple[float, float | None]:
    """The fill's time and SUMO's start: ``req.begin``, with a demand (``demand``: the files holding
    it) checked against its departures (its default: the first departure + the seeding's warm-up),
    SUMO starting at the configuration's begin, else the first departure."""
    from ..data.demand import DemandError, start_times
    if not demand:
        return (req.begin if req.begin is not None else 0.0), None
    try:
        start, begin, span = start_times(scen, {ln.edge for ln in net.lanes}, req.begin, demand)
    except DemandError as e:
        raise FillError(str(e)) from None
    if span.cut is not None:   # SUMO runs such a file up to the cut, as the fill's start does
        print(f"python -m sumo_scendiff.fill: warning: {span.cut.warning()}", file=sys.stderr)
    return begin, start


def _tiles(req: FillRequest, net) -> list:
    from ..map.raster import RasterConfig
    from .tiles import TileError, tile_grid, whole_area
    try:
        tiles = tile_grid(net, whole_area(net, req.area), req.stride, RasterConfig().size)
    except TileError as e:
        raise FillError(str(e)) from None
    if not tiles:
        _no_road(req, net)
    return tiles


def _area_has_road(req: FillRequest, net) -> None:
    """Raises FillError where ``req.area`` holds no car lane (SUMO's own start keeps nothing there)."""
    import shapely

    from .tiles import whole_area
    if req.area is not None and net.car_lane_km_in(shapely.box(*whole_area(net, req.area))) <= 0:
        _no_road(req, net)


def _no_road(req: FillRequest, net):
    raise FillError(f"--area: no car lane inside {','.join(f'{v:g}' for v in req.area)} (the network's "
                    f"car lanes span {','.join(f'{v:.0f}' for v in net.bounds)})")


def _sim_config(req: FillRequest, scen, begin: float):
    """SUMO's configuration of the fill: the network and additional files (the demand goes into the
    folder's configurations), the scenario's step and options but its mesoscopic model (the fill is
    microscopic: sim.scenario.meso_notice), starting at ``begin``. A user's scenario goes on under its
    own SUMO seed (sim.scenario.own_random), a bare network under ``-s``."""
    from ..sim.scenario import own_random
    from ..sim.sumo import SimConfig, settings
    seed, rng = own_random(scen) if scen.config or scen.routes else (req.seed, ())
    return SimConfig(net=scen.net, additional=scen.additional, seed=seed, begin=begin, extra=rng,
                     **settings(req, scen, mesoscopic=False))


def _nothing_to_fill(folder: str, req: FillRequest, scen, why: str) -> dict:
    """A scenario stock SUMO runs on which the model has nowhere to draw a vehicle (a railway): the
    folder holds fill.json alone, saying why; no state, nothing to run (README: bad input)."""
    import json

    from .output import FORMAT, VERSION
    doc = {"format": FORMAT, "version": VERSION, "network": os.path.abspath(scen.net),
           "configuration": scen.config, "begin": req.begin, "seed": req.seed, "nothing_to_generate": why,
           "summary": {"tiles": 0, "kept": 0, "vehicles": 0}, "tiles": [], "agents": [], "files": ["fill.json"]}
    with open(os.path.join(folder, "fill.json"), "w") as f:
        json.dump(doc, f, indent=1)
    return doc


def plan_amount(req: FillRequest, net, gen, tiles, scen, begin: float, demand: tuple[str, ...] = ()):
    """How much traffic each tile gets (fill/amount.py), made whole counts where the model is given it;
    ``demand``: the files holding the scenario's demand."""
    import shapely

    from .amount import AmountError, tile_amount
    from .plan import whole_counts
    if demand:
        phase(req.progress, f"routing the demand (duarouter) and estimating its vehicles at {begin:g} s")
    try:
        amount = tile_amount(req, net, gen, tiles, scen, begin, demand)
    except AmountError as e:
        raise FillError(str(e)) from None
    if amount.applied and amount.targets is not None:
        # the counts the tiles' cores keep (generator: round(D x car-lane km)) add up to the total
        kms = [net.car_lane_km_in(shapely.box(*t.core)) for t in tiles]
        amount.targets = whole_counts(amount.targets, kms)
        amount.source["vehicles_planned"] = int(round(sum(d * km for d, km in zip(amount.targets, kms)
                                                          if d is not None)))
    return amount


def user_errors() -> tuple[type, ...]:
    """The errors that are the user's input, one line and exit 2; imported only when one is raised,
    so that a bad input is answered before torch is loaded."""
    from ..core.outputs import OutputError
    from ..core.pool import EngineError
    from ..export.opendrive import ExportError
    from ..map.network import NetworkError
    from ..model.checkpoint import CheckpointError
    from ..sim.sumo import SimError
    from .inflow import InflowError
    return FillError, NetworkError, CheckpointError, SimError, OutputError, InflowError, EngineError, ExportError


__all__ = ["Fill", "FillError", "FillRequest", "Interrupted", "fill", "fill_into", "fill_request", "user_errors"]
