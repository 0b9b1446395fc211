"""Whole-network fill: generated traffic on every car lane of a network, a filled start for SUMO.

``fill.api.fill(network, amount, area, ...)`` (the library call) and ``python -m sumo_scendiff.fill``
(its CLI; docs/fill.md). :mod:`.tiles` lays the agreeing tile grid, :mod:`.plan` generates it colour by
colour, :mod:`.amount` sets each tile's level (a density, edgeData, a demand's estimate from
:mod:`.demand`), :mod:`.seed` puts the fill into one SUMO and writes its start files, :mod:`.output`
the folder. With a demand the default start is SUMO's own run to --begin (:mod:`.warm_start`).
"""
