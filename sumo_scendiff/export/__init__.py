"""Scenes that leave SUMO: ASAM OpenSCENARIO 1.2 (``scenario.xosc``) and OpenDRIVE (``scenario.xodr``)
beside a scene folder's SUMO files (docs/openscenario.md).

    from sumo_scendiff.export.openscenario import export_folder
    record = export_folder("out/scene_000")      # writes scenario.xodr, scenario.xosc, openscenario.json

Command line: ``python -m sumo_scendiff.export DIR... --format openscenario``; ``--export openscenario``
on ``run``, sweeps and the fill. Reading such a file back as tokens is the token reader's
(:mod:`sumo_scendiff.tokens.xosc`), so that generation does not depend on this room.
"""
