"""One window's request to the generator, built the same way by ``run``, sweeps and the
co-simulation API: the user's agent tokens and the vehicles already there as tokens, the global
p_mask token, the density target and the traffic lights the scene meets.

    existing = cosim.existing(window)                      # the host's vehicles around the window
    req = window_request(net, sim, window, existing, spec.for_window(window), p_mask=None, density="auto")
    scenes = generator.generate(net, [req.window], seed=0, **generation_inputs([req]))

The rules, once: a p_mask given (flag, token file, sweep value, API argument) is kept, else
``tokens.file.default_p_mask`` of every token the window has (the user's and the vehicles already
there); a level given as a density or a vehicle count, else the host's own where it has traffic
(``sim.density.default_density``); a target the model cannot take raises :class:`DensityUnsupported`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

from ..core.geometry import Window
from ..generation.token_check import heading_warnings
from ..generation.token_resolve import resolve_tokens
from ..tokens.file import default_p_mask
from .density import default_density, host_has_traffic, window_target
from .lights import light_states


class DensityUnsupported(ValueError):
    """A traffic level was asked of a model trained without the density condition; ``target`` is
    the level in vehicles per km of car lane."""

    def __init__(self, target: float, message: str | None = None):
        super().__init__(message or f"{target:.1f} veh/km asked of a model without the density condition")
        self.target = target


@dataclass
class WindowRequest:
    """What the generator is asked for one window, and what the seeding needs to match it."""
    window: Window
    tokens: list[dict]            # the user's (road references resolved), then the vehicles already there
    sources: list[str]            # per token: "user" or the id of the vehicle already there
    existing: object              # sim.cosim.Existing: the host's vehicles around the window
    p_mask: float
    target: float | None          # vehicles per km of car lane; None: the model's own level
    lights: dict[str, str] | None  # tls id -> state, when the generation conditions on lights
    warnings: list[str] = field(default_factory=list)   # the user's tokens heading against their road


def counted_as_asked(config, vehicles: int | None):
    """``config`` (GenerationConfig) counting a window's vehicles as the level was asked: a density in
    veh/km (a number, "auto", the host's) as SUMO's edgeData counts it (fronts on normal edges), a
    vehicle count (``vehicles``) one vehicle at a time."""
    return replace(config, count_on_edges=vehicles is None)


def density_target(net, window: Window, density=None, vehicles: int | None = None, sim=None,
                   has_density: bool = True, edge_data=None, time: float | None = None) -> float | None:
    """The window's density target (veh per km of car lane, vehicles already there included) from
    ``density`` (a number, "auto", "model") or ``vehicles``; neither: the host ``sim``'s own level
    where it has traffic (None: no host). Raises :class:`DensityUnsupported` for a target a model
    without the density condition (``has_density`` False) cannot take."""
    level = default_density(density, vehicles, host_has_traffic(sim), has_density)
    target = window_target(net, window, level, vehicles, sim=sim, edge_data=edge_data, time=time)
    if target is not None and not has_density:
        raise DensityUnsupported(target)
    return target


def window_request(net, sim, window: Window, existing, user_tokens: Sequence[dict] = (), *,
                   source: str = "tokens", fleet=None, p_mask: float | None = None, density=None,
                   vehicles: int | None = None, host: bool = True, has_density: bool = True,
                   edge_data=None, signals: bool = False) -> WindowRequest:
    """The request for ``window`` of the running simulation ``sim`` (at the seeding time).

    ``existing``: its vehicles around the window (``CoSimulation.existing``); ``user_tokens``: the
    user's agent tokens in the window's frame, ``source`` naming them in errors; ``fleet``
    (sim.fleet.Fleet): the scenario's vTypes, giving a token's named vType its size; ``host``:
    whether ``sim``'s traffic sets the "auto" level (False: a simulation without demand);
    ``edge_data``: the level of "auto" read at ``sim``'s time instead; ``signals``: whether the
    generation conditions on the lights."""
    said: list[str] = []       # a place this window's road does not have: a warning, not an error
    user = list(resolve_tokens(net, window, list(user_tokens), source, said))
    if fleet is not None:
        user = fleet.token_vtypes(user, source)
    tokens = user + existing.tokens()
    time = float(sim.simulation.getTime()) if edge_data is not None else None
    target = density_target(net, window, density, vehicles, sim=sim if host else None,
                            has_density=has_density, edge_data=edge_data, time=time)
    return WindowRequest(
        window=window, tokens=tokens, sources=["user"] * len(user) + existing.token_ids(),
        existing=existing, p_mask=p_mask if p_mask is not None else default_p_mask(tokens),
        target=target, lights=light_states(sim, net.lights_in(window)) if signals else None,
        warnings=said + heading_warnings(net, window, user))


def generation_inputs(requests: Sequence[WindowRequest]) -> dict:
    """``ScenarioGenerator.generate``'s per-window arguments for ``requests`` (their windows in
    order): tokens, p_mask, density (None where no window has a target) and signals."""
    targets = [r.target for r in requests]
    return {"tokens": [r.tokens for r in requests], "p_mask": [r.p_mask for r in requests],
            "density": targets if any(t is not None for t in targets) else None,
            "signals": [r.lights for r in requests]}
