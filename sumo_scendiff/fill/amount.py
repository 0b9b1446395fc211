"""How much traffic each tile of a fill gets: a density, an edgeData file's, a demand's, or the prior.

    amount = tile_amount(req, net, gen, tiles, scen, begin)
    amount.targets      # per tile veh/km (None: the model's prior)
    amount.applied      # whether the model is given them (its density condition)
    amount.source       # fill.json's "density" record
    amount.placed       # with a demand: its vehicles en route, placed on their lanes (fill/en_route.py)
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import shapely

# how the demand's estimate is made, for fill.json (docs/fill.md has the measurements)
ESTIMATE_METHOD = (
    "each departure before the state's time (--begin + one step) laid on the route SUMO's duarouter gives it "
    "and moved by fill/travel.py's clock: its vType's desired speed (x 0.9), the junctions' internal lanes, "
    "giving way, fixed lights as SUMO runs their programs (queues first come, first served), actuated ones at "
    "the cycle their gap control runs, the start from standing where it departs at speed 0 (its departSpeed, "
    "else SUMO's default.departspeed); queues on the lanes that lead on along each route, spilling back where "
    "they are full (fill/queues.py); no simulation")
PLACED_METHOD = (
    "each en-route vehicle on a lane of its edge from which its route goes on, waiting ones queued from the "
    "stop line, moving ones where their time on the edge brought them; given to its tile as a token (pose and "
    "size), the model draws its speed and path; it drives its own route on")


class AmountError(ValueError):
    """One line naming the flag or file."""


@dataclass
class Amount:
    targets: list | None
    applied: bool
    source: dict
    placed: list | None = None


def tile_amount(req, net, gen, tiles, scen, begin: float, demand=()) -> Amount:
    """Per tile the density target of ``req`` (fill.api.FillRequest) on ``net``'s ``tiles`` at
    ``begin``; ``scen``: the user's scenario (its additional files and options), ``demand``: the
    files holding its demand (its route files and additional files with vehicles:
    data.demand.demand_files)."""
    name = req.checkpoint or "the shipped model"
    if (req.density is not None or req.edge_data) and not gen.has_density:
        flag = "--density" if req.density is not None else "--edge-data"
        raise AmountError(f"{flag}: {name} has no density condition (trained before it); leave it out "
                          f"for the model's prior, or use --p-mask (lower: fewer vehicles) as the fallback")
    if req.density is not None:
        return Amount([req.density] * len(tiles), True, {"kind": "density", "veh_per_km": req.density,
                                                         "applied": True})
    if req.edge_data:
        return _edge_data(req.edge_data, net, tiles, begin)
    if demand:
        return _demand(req, net, gen, tiles, scen, begin, demand)
    return Amount(None, False, {"kind": "prior", "p_mask": req.p_mask, "applied": False})


def _edge_data(path: str, net, tiles, begin: float) -> Amount:
    from ..map.edgedata import EdgeData, EdgeDataError
    try:
        data = EdgeData.read(path, net)
        targets = [data.region_density(net, shapely.box(*t.core), begin) for t in tiles]
    except EdgeDataError as e:
        raise AmountError(f"--edge-data: {e}") from None
    return Amount(targets, True, {"kind": "edge-data", "file": os.path.abspath(path), "time": begin,
                                  "applied": True})


def _estimate(req, net, scen, begin: float, demand):
    """The demand's vehicles en route at ``begin`` (fill/demand.py), without simulating."""
    from ..core.sumo_xml import boolean
    from ..sim.scenario import own_random
    from ..sim.sumo import step_length_for
    from .demand import DemandEstimate
    from .routing import RoutingError
    options = dict(scen.options)
    try:
        # the state is saved one seeding step after begin: the departures before then are the fill's
        return DemandEstimate.at(net, list(scen.routes), begin, additional=scen.additional,
                                 due=begin + step_length_for(scen, req.step_length),
                                 depart_speed=options.get("default.departspeed"),
                                 junction_taz=boolean(options.get("junction-taz")), scale=options.get("scale"),
                                 # its random routes are those the user's own seed draws
                                 sumo_random=own_random(scen))
    except RoutingError as e:
        raise AmountError(f"{', '.join(demand)}: {e}") from None


def _demand(req, net, gen, tiles, scen, begin: float, demand) -> Amount:
    est = _estimate(req, net, scen, begin, demand)
    # each tile's count is kept in its core: the core's own density, so the tiles add up to the
    # estimate (a window's would spread a vehicle over every tile whose window sees it)
    targets = [est.region_density(net, shapely.box(*t.core)) for t in tiles]
    src = {"kind": "demand", "time": begin, "en_route": est.vehicles, "departed": est.departed,
           "unrouted": est.unrouted, "applied": gen.has_density, "method": ESTIMATE_METHOD}
    if not gen.has_density:
        src["note"] = (f"{req.checkpoint or 'the shipped model'} has no density condition: the demand's density "
                       f"is recorded per tile (target) but generation uses the model's prior scaled by "
                       f"--p-mask {req.p_mask:g}")
    if req.demand_level_only:
        return Amount(targets, gen.has_density, src)
    placed = _placed(req, net, tiles, scen, est, targets, src)
    return Amount(targets, gen.has_density, src, placed)


def _placed(req, net, tiles, scen, est, targets: list, src: dict) -> list:
    """The estimate's vehicles placed on their lanes, each given to the tile whose core holds it;
    ``targets`` become each core's count of them, ``src`` records how many."""
    from .en_route import allows, place_en_route
    from .plan import demand_tiles
    from .vtypes import vtype_bodies, vtype_table
    files = [*scen.routes, *scen.additional]
    classes = vtype_table(files, lambda el: el.get("vClass") or "passenger")
    placed, skipped = place_en_route(net, est, vtype_bodies(files), classes)
    # each core keeps the vehicles placed in it: an edge's queue stands in the core of its stop
    # line, not spread over the edge as the per-edge density has it
    owner = demand_tiles(tiles, placed, req.area)
    per_tile = np.bincount([k for k in owner if k is not None], minlength=len(tiles))
    for t in tiles:
        km = net.car_lane_km_in(shapely.box(*t.core))
        targets[t.index] = float(per_tile[t.index]) / km if km > 0 else None
    kept = [p for p, k in zip(placed, owner) if k is not None]
    # trams, bicycles on their bike lanes: no car lane of their edge is theirs
    off = sum(not any(ln.car and ln.edge == v.edges[0] and allows(net, i, classes.get(v.type, "passenger"))
                      for i, ln in enumerate(net.lanes)) for v in skipped)
    src["vehicles"] = {"placed": len(kept), "no_room": len(skipped) - off, "no_car_lane": off,
                       "outside": len(owner) - len(kept), "method": PLACED_METHOD}
    return kept


__all__ = ["Amount", "AmountError", "tile_amount"]
