"""What a token may say, without torch: the feature names and which of them pin an agent.

Encoding (torch) lives in :mod:`.encoding`; the exporter and the token-file reader only need these
names.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

FEATURES: tuple[str, ...] = ("x", "y", "heading", "length", "width", "speed", "final_speed",
                             "heading_to_final")

# what a token says to the seeder, not to the model: the scenario's vType its vehicle is (sim/fleet.py),
# the class it is (generation/scene_passes.py: the model's box for a bus is often truck-long)
SEEDING_KEYS = ("vtype", "vclass")

# every feature a pinned agent needs: pose, size and speed (generation.pinning)
PIN_FEATURES = ("x", "y", "heading", "length", "width", "speed")


class TokenError(ValueError):
    """Invalid user-provided token features (one-line message naming the problem)."""


def is_pinnable(token: Mapping) -> bool:
    """Whether a token dict gives every feature a pinned agent needs (:data:`PIN_FEATURES`)."""
    return all(token.get(f) is not None and np.isfinite(float(token[f])) for f in PIN_FEATURES)
