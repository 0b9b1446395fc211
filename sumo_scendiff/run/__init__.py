"""The ``run`` command: generate scenes on a SUMO network, seed them as real SUMO vehicles, let SUMO
drive, export (``python -m sumo_scendiff.run``; its flags and what it writes: :mod:`.cli`). The
command line is :mod:`.cli` (flags, checks, the summary it prints, exit codes); what it does with
them is :mod:`.scenes` (the scenario, the warm-up, the windows, generation, each scene's folder).

    o = get_options(["-n", "networks/city.net.xml", "--scenes", "2"])
    summary = run(o)         # run.json's content; RunError: a problem with the user's input
"""
from __future__ import annotations

from .cli import get_options, main, print_summary
from .scenes import PROG, RunError, run

__all__ = ["PROG", "RunError", "get_options", "main", "print_summary", "run"]
