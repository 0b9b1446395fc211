"""What became of each generated agent at seeding: one record per agent, the records adding up.

Every generated agent is exactly one of :data:`STATUSES` (:meth:`SeedReport.status`, and
:func:`before_status` for those never handed to the seeder): ``placed`` (in SUMO where it was
generated), ``misplaced`` (in SUMO, off its pose), ``refused`` (SUMO's reason), ``existing`` (the
model's copy of a vehicle already in the simulation: that vehicle is kept as it is, the copy not
added) or ``dropped`` (the seeder's own rule's reason); ``scene.json`` and ``fill.json`` count them
so that generated = placed + misplaced + refused + existing + dropped. The other fields say how a seeded vehicle was
fitted (slowed, a minGap fitted, pulled back behind its lane's end, narrowed, moved to a stop line).
"""
from __future__ import annotations

from dataclasses import dataclass, field

SEEDED = ("placed", "misplaced", "refused")   # the statuses of the agents handed to SUMO (a placement's share)
STATUSES = (*SEEDED, "existing", "dropped")   # every generated agent is exactly one


@dataclass
class SeedReport:
    ids: dict[int, str] = field(default_factory=dict)        # agent index -> vehicle id
    refused: dict[int, str] = field(default_factory=dict)    # agent index -> reason
    misplaced: dict[int, float] = field(default_factory=dict)  # agent index -> position error (m)
    targets: dict[int, tuple] = field(default_factory=dict)  # agent index -> (x_front, y_front, angle)
    slowed: dict[int, tuple] = field(default_factory=dict)   # agent index -> (generated, departure speed)
    gap_fitted: dict[int, tuple] = field(default_factory=dict)  # agent index -> (minGap, minGap fitted)
    dropped: dict[int, str] = field(default_factory=dict)    # agent index -> why our own rules did not seed it
    pulled_back: dict[int, float] = field(default_factory=dict)  # agent index -> m moved behind its lane's end
    narrowed: dict[int, tuple] = field(default_factory=dict)  # agent index -> (generated, SUMO width), width_cap
    to_stop_line: dict[int, float] = field(default_factory=dict)  # agent index -> m moved from a red junction
    own_route: dict[int, str] = field(default_factory=dict)  # agent index -> how its given route went (RouteChooser.along)
    lanes: dict[int, tuple] = field(default_factory=dict)     # agent index -> (normal lane id, front pos) seeded on

    @property
    def placed(self) -> int:
        return len(self.ids) - len(self.misplaced)

    @property
    def conflicts(self) -> dict[int, str]:
        """The agents not seeded by the seeder's own rules: :attr:`dropped` (its earlier name)."""
        return self.dropped

    def status(self, i: int) -> tuple[str, str | float | None]:
        """Agent ``i``'s record: ``placed`` (None), ``misplaced`` (its position error, m), ``refused``
        (SUMO's reason) or ``dropped`` (the rule's reason); exactly one (README, scene.json). Never
        ``existing``: the model's copies of vehicles already there are not handed to the seeder
        (:func:`before_status`)."""
        if i in self.dropped:
            return "dropped", self.dropped[i]
        if i in self.refused:
            return "refused", self.refused[i]
        if i in self.misplaced:
            return "misplaced", self.misplaced[i]
        if i in self.ids:
            return "placed", None
        return "dropped", "not seeded"   # an index the seeding never reached: not in SUMO, never "placed"

    def counts(self, generated: int) -> dict[str, int]:
        """Each status's count (:data:`STATUSES`) of a scene of ``generated`` agents, all handed to the
        seeder (none ``existing``)."""
        out = {"generated": generated, **dict.fromkeys(STATUSES, 0)}
        for i in range(generated):
            out[self.status(i)[0]] += 1
        return out


def before_status(token: int | None, token_source) -> str:
    """The status of a generated agent not handed to the seeder for a vehicle already in the
    simulation (sim.cosim.on_existing): ``existing`` where it is the model's copy of that vehicle (its
    token is the vehicle's: ``token_source[token]`` names it), else ``dropped`` (its box on one)."""
    return "existing" if token is not None and token_source[token] != "user" else "dropped"
