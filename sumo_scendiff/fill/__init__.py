"""Whole-network fill: generated traffic on every car lane of a network, a filled start for SUMO.

``python -m sumo_scendiff.fill`` (docs/fill.md). :mod:`.tiles` lays the agreeing tile grid,
:mod:`.plan` generates it colour by colour, :mod:`.demand` estimates a demand's density at a time,
:mod:`.seed` puts the fill into one SUMO and writes its start files, :mod:`.output` the folder.
"""
