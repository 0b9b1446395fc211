"""How long the studio's page takes to redraw a network (docs/studio.md, "Speed").

    python benchmarks/studio_redraw.py /work/shared/nets/ingolstadt_cutmap/Forschungskreuzung_cutmap.net.xml.gz

Starts the studio on a free port, opens it in headless Chromium (/usr/bin/chromium, playwright) at
1400 x 900 and times 30 frames of each kind: a pan (3 px), a zoom step (1 %), the first frame once a
zoom rests (one band drawn sharp) and the whole view drawn anew, each until its pixels are written
(getImageData), at three zooms: the whole network, 1 px/m and 4 px/m. Prints the median and the
second-worst in ms.
"""
from __future__ import annotations

import socket
import sys
import tempfile
import threading
import time

ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]
# one frame of each kind, timed until its pixels are written: [what comes before it, the frame]. A pan shifts
# the network's layer and draws the strips uncovered; a zoom step scales the layer; once a zoom rests the
# scaled picture becomes the layer and is drawn sharp a band a frame (one band timed); "anew" draws the
# whole view in one frame (a new look of the network, a resize, a jump)
STEPS = {"pan": ["studio.view.ox += 3;", "draw();"],
         "zoom": ["studio.view.s *= 1.01;", "draw();"],
         "rest": ["studio.view.s *= 1.01;", "restLayer(window.devicePixelRatio || 1); draw();"],
         "anew": ["studio.view.ox += 3; dropLayer();", "draw();"]}
TIMES = """([before, frame]) => { dropLayer(); draw();
                      const ms = []; for (let i = 0; i < 30; i++) { const s0 = studio.view.s; eval(before);
                      const t0 = performance.now(); eval(frame); ctx.getImageData(0, 0, 1, 1); ms.push(performance.now() - t0);
                      studio.view.s = s0; }
                      ms.sort((a, b) => a - b); return [ms[15], ms[28]]; }"""
ZOOM = """(s) => { const c = document.getElementById('canvas'), b = studio.net.bounds;
                   const x = (b[0] + b[2]) / 2, y = (b[1] + b[3]) / 2;
                   studio.view = {s, ox: c.clientWidth / 2 - s * x, oy: c.clientHeight / 2 + s * y}; }"""


def serve(net: str, out: str) -> str:
    import uvicorn

    from sumo_scendiff.studio.app import make_app
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(make_app(net, None, out, warm=False), log_level="warning"))
    threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    return f"http://127.0.0.1:{sock.getsockname()[1]}/"


def main(net: str) -> None:
    from playwright.sync_api import sync_playwright
    url = serve(net, tempfile.mkdtemp(prefix="studio-redraw-"))
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        t = time.perf_counter()
        page.goto(url)
        page.wait_for_function("window.studio && window.studio.ready", timeout=120000)
        print(f"{net}: {page.evaluate('studio.net.lanes.length')} lanes, page ready in {time.perf_counter() - t:.1f} s")
        for name, zoom in (("whole network", None), ("1 px/m", 1.0), ("4 px/m", 4.0)):
            if zoom is not None:
                page.evaluate(ZOOM, zoom)
            ms = {k: page.evaluate(TIMES, step) for k, step in STEPS.items()}
            print(f"{name:14} " + "; ".join(f"{k}: median {m:5.1f} ms, 2nd worst {w:5.1f} ms" for k, (m, w) in ms.items()))
        browser.close()


if __name__ == "__main__":
    main(sys.argv[1])
