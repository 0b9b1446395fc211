"""Traffic-light states as the map sees them: which controlled link may go, which must stop.

A SUMO traffic light's state is a string with one character per controlled link (``tlLogic`` /
``traci.trafficlight.getRedYellowGreenState``): ``G`` priority green, ``g`` green that yields, ``s``
green after a stop (right turn on red), ``y`` amber, ``r`` red, ``u`` red-amber, ``o``/``O`` off.
A link runs from an incoming lane over its junction-internal (via) lane to an outgoing lane.

    links = signal_links(net)                       # every controlled link of the network
    states = {"J3": "GGrrGGrr"}                     # tls id -> state at t = 0 of a scene
    text = encode_states(states); decode_states(text) == states   # as stored in data shards

The raster draws each link's state on its via lane and on the last :data:`APPROACH_M` metres of
its incoming lane (where a queue stands at red): :func:`link_values` gives the two channels' values.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

APPROACH_M = 20.0   # metres of the incoming lane before the stop line drawn with the link's state
# channel values per state character: "go" (may enter the junction), "stop" (must wait at the line)
GO = {"G": 1.0, "g": 0.5, "s": 0.5}
STOP = {"r": 1.0, "u": 1.0, "y": 0.5, "Y": 0.5}


@dataclass(frozen=True)
class SignalLink:
    tls: str
    index: int          # position in the light's state string
    lane: int           # incoming lane (index into net.lanes)
    via: int            # junction-internal lane (index into net.lanes), -1 where the net has none


def signal_links(net) -> list[SignalLink]:
    """Every traffic-light-controlled link of ``net`` (a :class:`~.network.Network`), from sumolib."""
    out = []
    for edge in net.sumo_net.getEdges(withInternal=False):
        for lane in edge.getLanes():
            for conn in lane.getOutgoing():
                tls = conn.getTLSID()
                if not tls or conn.getTLLinkIndex() < 0:
                    continue
                src = net.lane_index.get(lane.getID())
                if src is None:
                    continue
                via = net.lane_index.get(conn.getViaLaneID() or "", -1)
                out.append(SignalLink(tls, int(conn.getTLLinkIndex()), src, via))
    return out


RED, GREEN = "rRu", "Gg"   # a lane's light is red / green when every link from it shows one of these


def lane_lights(net, states: dict[str, str]) -> dict[int, str]:
    """Per lane (Network.lanes index) that a light controls, ``"red"`` or ``"green"`` when every
    link from it shows one (:data:`RED`, :data:`GREEN`) in ``states`` (tls id -> state string);
    lanes with mixed or unknown links are left out."""
    chars: dict[int, list[str]] = {}
    for link in net.signal_links:
        state = states.get(link.tls)
        if state is not None and link.index < len(state):
            chars.setdefault(int(link.lane), []).append(state[link.index])
    out = {}
    for lane, cs in chars.items():
        if all(c in RED for c in cs):
            out[lane] = "red"
        elif all(c in GREEN for c in cs):
            out[lane] = "green"
    return out


def encode_states(states: dict[str, str]) -> str:
    """``{"J3": "GGrr"}`` -> ``"J3=GGrr"`` (sorted, ``|``-separated): one string per scene in a shard."""
    return "|".join(f"{k}={v}" for k, v in sorted(states.items()))


def decode_states(text: str) -> dict[str, str]:
    if not text:
        return {}
    return dict(part.rsplit("=", 1) for part in text.split("|"))


def link_values(links: list[SignalLink], states: dict[str, str]) -> tuple[np.ndarray, np.ndarray]:
    """(go, stop) value of each link under ``states``; 0 where its light is not in ``states``."""
    go = np.zeros(len(links), np.float32)
    stop = np.zeros(len(links), np.float32)
    for k, ln in enumerate(links):
        state = states.get(ln.tls)
        if state is None or ln.index >= len(state):
            continue
        c = state[ln.index]
        go[k], stop[k] = GO.get(c, 0.0), STOP.get(c, 0.0)
    return go, stop


def approach(shape: np.ndarray, metres: float = APPROACH_M) -> np.ndarray:
    """The last ``metres`` of a polyline (K, 2), as a polyline."""
    seg = np.hypot(*np.diff(shape, axis=0).T)
    if len(seg) == 0:
        return shape
    back = np.concatenate([[0.0], np.cumsum(seg[::-1])])   # distance from the end at each vertex, reversed
    k = int(np.searchsorted(back, metres))
    if k >= len(back):
        return shape
    rev = shape[::-1]
    f = (metres - back[k - 1]) / max(seg[::-1][k - 1], 1e-9)
    cut = rev[k - 1] + f * (rev[k] - rev[k - 1])
    return np.concatenate([[cut], rev[: k][::-1]])
