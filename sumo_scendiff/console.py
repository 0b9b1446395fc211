"""The ``scendiff`` command: one entry point for every tool, each the same as its module.

    scendiff run -n networks/city.net.xml          # = python -m sumo_scendiff.run -n ...
    scendiff fill -n networks/city.net.xml -o filled/
    scendiff --help                                # the tools

``scendiff TOOL ARGS`` runs ``python -m sumo_scendiff.TOOL ARGS`` in this process: the same flags,
help, messages and exit codes.
"""
from __future__ import annotations

import runpy
import sys

TOOLS = {
    "run": "generate scenes on a network, seed them into SUMO, roll out, export",
    "fill": "fill a whole network with generated traffic: a filled start for stock SUMO",
    "sweep": "many scenarios from a spec file, on local processes or Ray",
    "evaluate": "metrics of generated scenes against recorded ones",
    "train": "train the autoencoder and the diffusion model (recipes)",
    "studio": "the local web app: place tokens on a map, generate, keep scenes",
    "data": "record SUMO traffic into training shards",
    "export": "scene folders as OpenSCENARIO + OpenDRIVE",
}


def usage() -> str:
    wide = max(map(len, TOOLS))
    return ("usage: scendiff TOOL [ARGS ...]   (scendiff TOOL --help: the tool's flags)\n\ntools:\n"
            + "".join(f"  {name:{wide}}  {what}\n" for name, what in TOOLS.items()))


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    if not args or args[0] in ("-h", "--help"):
        print(usage(), end="")
        return 0
    tool, rest = args[0], args[1:]
    if tool not in TOOLS:
        print(f"scendiff: error: unknown tool {tool!r} (one of {', '.join(TOOLS)}; scendiff --help)",
              file=sys.stderr)
        return 2
    sys.argv = [f"scendiff {tool}", *rest]
    try:   # as python -m runs it: the module is __main__, its own sys.exit ends the command
        runpy.run_module(f"sumo_scendiff.{tool}", run_name="__main__", alter_sys=True)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
