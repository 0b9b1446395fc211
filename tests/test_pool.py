"""core.pool: the engines behind the sweep's and the fill's workers (their real runs: test_sweep.py,
test_fill.py)."""
from __future__ import annotations

import pytest

from sumo_scendiff.core.pool import EngineError, InProcess, LocalPool


class _Echo:
    def run(self, *task):
        return task


def test_in_process_runs_tasks_in_order():
    with InProcess(_Echo()) as pool:
        assert list(pool.map_unordered([(1,), (2, 3)])) == [(0, (1,)), (1, (2, 3))]


def test_a_worker_that_cannot_start_is_an_error_not_a_hang():
    """A pool initializer that raises would be respawned forever; the pool reports it instead."""
    with LocalPool(int, ("not a number",), workers=1) as pool:
        with pytest.raises(EngineError, match="could not start.*ValueError"):
            list(pool.map_unordered([()]))
