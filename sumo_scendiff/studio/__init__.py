"""The scenario studio: a local web app to place a window and tokens on a network, generate, look, export.

    python -m sumo_scendiff.studio -n networks/city.net.xml -o studio-out

The server (:mod:`.app`) answers JSON; the page (``static/``) draws the network on a canvas. Generation
is ``run``'s own code path (:mod:`.generate`), so a scene kept here is the scene ``run`` writes for the
same window, tokens and seed (docs/studio.md).
"""
