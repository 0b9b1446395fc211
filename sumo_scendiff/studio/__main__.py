"""Start the scenario studio: a local web app to place tokens on a network, generate and export scenes.

    python -m sumo_scendiff.studio -n networks/city.net.xml
    python -m sumo_scendiff.studio -c scenario.sumocfg -o studio-out --port 8765

It prints the address to open in a browser (bound to 127.0.0.1 unless --host says otherwise). The
server reads only the files named here and writes only under -o (docs/studio.md).
"""
from __future__ import annotations

import argparse
import sys

PROG = "python -m sumo_scendiff.studio"


def get_options(args=None):
    from ..core.cli import HelpFormatter, description, epilog
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), epilog=epilog(__doc__),
                                formatter_class=HelpFormatter)
    p.add_argument("-n", "--net-file", "--net", dest="net", help="SUMO network (.net.xml[.gz])")
    p.add_argument("-c", "--configuration-file", dest="config", metavar="FILE",
                   help="a SUMO scenario (.sumocfg): its network, demand (windows around a vehicle) and vTypes")
    p.add_argument("-o", "--output-dir", dest="out", default="studio-out",
                   help="where kept scenes, token files and generation drafts are written (default studio-out)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8765, help="port (default 8765; 0: a free one)")
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("--steps", type=int, default=None,
                   help="denoising steps of each generation, run's --steps (default: run's): fewer for quicker drafts")
    o = p.parse_args(args)
    from ..sim.scenario import input_flags_problem
    if input_flags_problem(o.net, o.config):
        p.error(input_flags_problem(o.net, o.config))
    if o.steps is not None and o.steps < 1:
        p.error(f"--steps must be at least 1, got {o.steps}")
    if not 0 <= o.port < 65536:
        p.error(f"--port must be in 0..65535, got {o.port}")
    o.parser = p
    return o


def main(o) -> int:
    import socket

    import uvicorn

    from ..map.network import NetworkError
    from ..sim.scenario import ScenarioError
    from .app import StudioError, make_app
    try:
        app = make_app(o.net, o.config, o.out, checkpoint=o.checkpoint, steps=o.steps)
    except (NetworkError, ScenarioError, StudioError, OSError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    sock = socket.socket()
    try:
        sock.bind((o.host, o.port))
    except OSError as e:
        o.parser.exit(2, f"{PROG}: error: --port {o.port}: {e.strerror}\n")
    host, port = sock.getsockname()[:2]
    print(f"scenario studio on {app.state.studio.name}: open http://{host}:{port}/ (Ctrl-C stops it)", flush=True)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
    server.run(sockets=[sock])
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
