"""The scenario studio: its real server on a free port (netgenerate's 3x3 grid with sidewalks), and the page in a real
headless Chromium (Debian's ``chromium``, driven by playwright's Python package) where there is one.

A scene kept in the studio is a folder stock SUMO replays, and the same scene as ``run`` writes with the
command the studio shows and the token file it saved (byte for byte).
"""
from __future__ import annotations

import gzip
import json
import os
import shlex
import shutil
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request

import pytest

pytest.importorskip("starlette", reason="the studio's server library (pip install -e '.[studio]')")
uvicorn = pytest.importorskip("uvicorn", reason="the studio's server (pip install -e '.[studio]')")

ROOT = os.path.join(os.path.dirname(__file__), "..")
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
CENTER = [50.0, 98.0]          # a window on edge A1B1 (its lane 1 is a car lane at y 98.4, lane 0 a sidewalk at 95.8)
TOKEN = {"edge": "A1B1", "lane": 1, "pos": 60.0, "vclass": "bus", "speed": 6.0, "manoeuvre": "stop"}
# -o with a space, quotes and a dollar: every path the studio writes, shows or runs must survive them
AWKWARD = "out dir 'q' \"$x\""
STEPS = 2   # denoising steps (the studio's --steps): a quick draft, still run's scene byte for byte


@pytest.fixture(scope="module")
def net(tmp_path_factory) -> str:
    """A tiny network: netgenerate's 3x3 grid, 100 m blocks, sidewalks, a traffic light at B1."""
    from sumo_scendiff.core.tools import sumo_binary
    out = str(tmp_path_factory.mktemp("net") / "tiny.net.xml")
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
                    "--sidewalks.guess", "true", "--tls.set", "B1", "-o", out], check=True, capture_output=True)
    return out


@pytest.fixture(scope="module")
def studio_app(tmp_path_factory, net):
    """The studio's app, as ``python -m sumo_scendiff.studio --steps 2`` makes it (its model loading in the
    background)."""
    from sumo_scendiff.studio.app import make_app
    return make_app(net, None, str(tmp_path_factory.mktemp("studio") / AWKWARD), steps=STEPS)


@pytest.fixture(scope="module")
def studio(studio_app):
    """The studio's app under uvicorn on a free port of 127.0.0.1 (one server for the module's tests)."""
    app, out = studio_app, studio_app.state.studio.out
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    while not server.started:
        if not thread.is_alive():
            pytest.fail("the studio's server did not start")
        time.sleep(0.05)
    yield f"http://127.0.0.1:{sock.getsockname()[1]}", out
    server.should_exit = True
    thread.join()


def call(url: str, body=None, raw: bytes | None = None) -> tuple[int, dict]:
    data = raw if raw is not None else None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req) as r:
            return r.status, json.load(r)
    except urllib.error.HTTPError as e:
        return e.code, json.load(e)


def test_network_geometry_is_the_projects_network(studio, net):
    from sumo_scendiff.map.network import Network
    url, _ = studio
    status, doc = call(f"{url}/api/network")
    network = Network.load(net)
    assert status == 200 and doc["name"] == "tiny"
    assert [ln["id"] for ln in doc["lanes"]] == [ln.id for ln in network.lanes]
    lane = next(ln for ln in doc["lanes"] if ln["id"] == "A1B1_1")
    assert lane["kind"] == "car" and len(lane["shape"]) == 2 * len(network.lanes[network.lane_index["A1B1_1"]].shape)
    assert next(ln for ln in doc["lanes"] if ln["id"] == "A1B1_0")["kind"] == "walk"
    assert len(doc["junctions"]) > 0 and all(len(j["ring"]) >= 6 for j in doc["junctions"])
    tls = {ln.id for ln in network.lanes if ln.tls and not ln.internal}
    assert tls and {lt["lane"] for lt in doc["lights"]} == tls


def test_snap_finds_the_car_lane_not_the_sidewalk(studio):
    url, _ = studio
    status, s = call(f"{url}/api/snap", {"x": 50.0, "y": 97.0})    # nearer the sidewalk's centre line
    assert status == 200 and (s["lane"], s["edge"], s["index"]) == ("A1B1_1", "A1B1", 1)
    assert 0 <= s["pos"] <= s["length"] and abs(s["x"] - 50.0) < 2 and abs(s["y"] - 98.4) < 0.1
    status, err = call(f"{url}/api/snap", {"x": -5000.0, "y": 0.0})
    assert status == 400 and "no car lane within" in err["error"]


@pytest.mark.parametrize("path, body, raw, status, words", [
    ("/api/snap", None, b"{not json", 400, "not JSON"),
    ("/api/snap", {"x": "east", "y": 1}, None, 400, "x: expected a finite number"),
    ("/api/tokens", {"agents": [{"speed": -3}]}, None, 400, "must be >= 0"),
    ("/api/tokens", {"agents": [{"spede": 3}]}, None, 400, "unknown key 'spede'"),
    ("/api/generate", {"tokens": {}}, None, 400, "center: expected [x, y]"),
    ("/api/generate", {"center": CENTER, "density": -4}, None, 400, "density: expected a number"),
    ("/api/generate", {"center": [9000.0, 9000.0]}, None, 400, "off the network"),
    ("/api/generate", {"center": CENTER, "yaw": "north"}, None, 400, "yaw: expected a number"),
    ("/api/generate", {"center": CENTER, "tokens": {"agents": [{"edge": "nope", "pos": 3.0}]}}, None, 400,
     "no edge 'nope'"),
    ("/api/keep", {"draft": "../..", "scene": "scene_000", "name": "x"}, None, 400, "keep: expected"),
    ("/api/keep", {"draft": "gen-9999", "scene": "scene_000", "name": "x"}, None, 400, "no scene"),
    ("/api/fill", {"path": "../../../etc/passwd"}, None, 400, "no such file under the output directory"),
    ("/api/fill", {"fill": {"format": "other"}}, None, 400, "not a fill.json"),
    ("/api/open", {"name": "../.."}, None, 400, "expected the name of a kept folder"),
    ("/api/open", {"name": "never_kept"}, None, 400, "no kept scene of that name"),
    ("/api/nothing", None, None, 404, "/api/nothing"),
    ("/api/generate", None, None, 405, "/api/generate"),
])
def test_a_malformed_request_gets_a_4xx_with_one_line(studio, path, body, raw, status, words):
    url, _ = studio
    got, doc = call(f"{url}{path}", body, raw)
    assert got == status and words in doc["error"] and "Traceback" not in doc["error"]
    assert "\n" not in doc["error"]


def _replays(folder: str) -> None:
    from sumo_scendiff.core.tools import sumo_binary
    done = subprocess.run([sumo_binary(), "-c", os.path.join(folder, "scenario.sumocfg"), "--end", "1",
                           "--no-step-log"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def _same_as_run(kept: str, scene: str, command: str, tmp) -> None:
    """``run`` with the studio's command and the token file it kept writes the same scene, byte for byte."""
    args = shlex.split(command)[3:]
    args[args.index("--tokens") + 1] = os.path.join(kept, "tokens.toml")
    args[args.index("-o") + 1] = str(tmp / "cli")
    done = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", *args], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    cli = os.path.join(tmp, "cli", scene)
    for name in ("scene.json", "scenario.rou.xml", "scenario.sumocfg"):
        with open(os.path.join(kept, name), "rb") as a, open(os.path.join(cli, name), "rb") as b:
            assert a.read() == b.read(), name
    with gzip.open(os.path.join(kept, "state.xml.gz")) as a, gzip.open(os.path.join(cli, "state.xml.gz")) as b:
        # SUMO's header comment names the time of writing and the options; the state is what follows it
        assert a.read().split(b"-->", 1)[1] == b.read().split(b"-->", 1)[1]


def _is_a_bus(folder: str, vid: str) -> None:
    """The vehicle ``vid`` of a kept folder is a 12 m bus in SUMO's state and in the OpenSCENARIO export."""
    import xml.etree.ElementTree as ET
    with gzip.open(os.path.join(folder, "state.xml.gz")) as f:
        state = ET.parse(f).getroot()
    vtype = next(v.get("type") for v in state.iter("vehicle") if v.get("id") == vid)
    t = next(t for t in state.iter("vType") if t.get("id") == vtype)
    assert t.get("vClass") == "bus" and float(t.get("length")) == 12.0
    entity = next(e for e in ET.parse(os.path.join(folder, "scenario.xosc")).getroot().iter("ScenarioObject")
                  if any(p.get("name") == "sumo_id" and p.get("value") == vid for p in e.iter("Property")))
    assert entity.find("Vehicle").get("vehicleCategory") == "bus"


@pytest.mark.slow
def test_generate_keep_replay_and_run_gives_the_same_scene(studio, tmp_path):
    url, out = studio
    status, doc = call(f"{url}/api/generate", {"center": CENTER, "tokens": {"p_mask": 0.5, "agents": [TOKEN]},
                                               "scenes": 1, "seed": 3})
    assert status == 200, doc
    scene = doc["scenes"][0]
    assert scene["window"] == {"cx": CENTER[0], "cy": CENTER[1], "yaw": 0.0, "size": 100.0}
    from sumo_scendiff.sim.seed_report import STATUSES
    n = scene["counts"]   # records add up: each generated agent has one status
    assert sum(n[s] for s in STATUSES) == n["generated"] == len(scene["agents"])
    bus = [a for a in scene["agents"] if a["source"] == "user" and a["token"] == 0]
    # the token's class is its vehicle's, at the class's size (docs/tokens.md), though the model draws a bus
    # token's box about a truck's length: drawn, in scene.json and in SUMO a bus (the export's checked below)
    assert len(bus) == 1 and len(bus[0]["path"]) == 5
    assert bus[0]["vclass"] == "bus" and (bus[0]["length"], bus[0]["width"]) == pytest.approx((12.0, 2.55))
    assert all(a["reason"] for a in scene["agents"] if a["status"] in ("refused", "dropped"))
    assert 'manoeuvre = "stop"' in doc["tokens"] and "--seed 3" in doc["command"] and "--steps 2" in doc["command"]

    status, kept = call(f"{url}/api/keep", {"draft": doc["draft"], "scene": "scene_000", "name": "mine",
                                            "openscenario": True})
    assert status == 201, kept
    assert kept["folder"] == os.path.abspath(os.path.join(out, "mine")) and kept["openscenario"]
    assert {"scene.json", "scenario.sumocfg", "state.xml.gz", "tokens.toml"} <= set(kept["files"])
    assert any(f.endswith(".xosc") for f in os.listdir(kept["folder"]))
    _is_a_bus(kept["folder"], bus[0]["vehicle"])
    status, again = call(f"{url}/api/keep", {"draft": doc["draft"], "scene": "scene_000", "name": "mine"})
    assert status == 409 and "exists" in again["error"]   # nothing the user made is overwritten
    _replays(kept["folder"])
    _same_as_run(kept["folder"], "scene_000", doc["command"], tmp_path)

    # a fill-format file of the kept scene's vehicles colours the edge they stand on
    agents = json.load(open(os.path.join(kept["folder"], "scene.json")))["agents"]
    fill = {"format": "sumo-scendiff-fill", "agents": agents}
    with open(os.path.join(out, "fill.json"), "w") as f:
        json.dump(fill, f)
    status, dens = call(f"{url}/api/fill", {"path": "fill.json"})
    assert status == 200 and dens["vehicles"] == sum(a["vehicle"] is not None for a in agents)
    assert dens["edges"].get("A1B1", 0) > 0
    assert call(f"{url}/api/fill", {"fill": fill})[1] == dens


def _counted(reads: list, name: str, real):
    """``real``, each call noted in ``reads`` under ``name``."""
    def counted(*args, **kwargs):
        reads.append(name)
        return real(*args, **kwargs)
    return counted


@pytest.mark.slow
def test_a_generation_reads_neither_the_model_nor_the_network_again(studio, studio_app, monkeypatch):
    """The server holds its network and model for its life, and every run inside it is handed them
    (Network.load, ScenarioGenerator.load: what the process holds): a generation reads neither file."""
    import sumo_scendiff.map.network as network
    import sumo_scendiff.model.checkpoint as checkpoint
    url, _ = studio
    held = studio_app.state.studio
    assert held.warm.wait(600) and held.generator is not None
    reads = []
    monkeypatch.setattr(checkpoint, "load", _counted(reads, "checkpoint", checkpoint.load))
    monkeypatch.setattr(network, "read_entry", _counted(reads, "network cache", network.read_entry))
    monkeypatch.setattr(network.Network, "_read_file", classmethod(
        _counted(reads, "network file", network.Network._read_file.__func__)))
    status, doc = call(f"{url}/api/generate", {"center": CENTER, "scenes": 1, "seed": 5})
    assert status == 200, doc
    assert reads == [] and doc["scenes"][0]["counts"]["generated"] == len(doc["scenes"][0]["agents"])


def _no_display(monkeypatch) -> None:
    """This process (the server runs in it) as on a machine without a screen."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


def test_open_in_sumo_gui_without_a_display_gives_the_command(studio, net, monkeypatch):
    """No display: the server says so and answers the command, its path quoted for a shell; the argument
    list it would start sumo-gui with carries the path whole (stock sumo runs the scenario with it)."""
    from sumo_scendiff.core.tools import sumo_binary
    from sumo_scendiff.studio.gui import gui_args
    url, out = studio
    folder = os.path.join(out, "by_hand")      # a kept folder: a scenario stock SUMO runs
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "scenario.sumocfg"), "w") as f:
        f.write(f'<configuration><input><net-file value="{os.path.abspath(net)}"/></input></configuration>\n')
    cfg = os.path.abspath(os.path.join(folder, "scenario.sumocfg"))
    _no_display(monkeypatch)
    status, doc = call(f"{url}/api/open", {"name": "by_hand"})
    assert status == 200 and doc["launched"] is False and "no display" in doc["why"]
    assert shlex.split(doc["command"]) == ["sumo-gui", "-c", cfg] and "'" in AWKWARD and doc["config"] == cfg
    args = gui_args(cfg)
    assert args == [sumo_binary("sumo-gui"), "-c", cfg]
    done = subprocess.run([sumo_binary("sumo"), *args[1:], "--end", "1", "--no-step-log"], capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stderr


def _chromium_problem() -> str | None:
    if not os.path.exists(CHROMIUM):
        return f"no {CHROMIUM} (Debian's chromium package: apt-get install chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "no playwright (pip install -e '.[test]')"
    return None


@pytest.fixture(scope="module")
def page(studio):
    """One headless Chromium and one page on the studio for the module's browser tests (loaded, drawn);
    yields the page and the script errors it raised."""
    if _chromium_problem():
        pytest.skip(_chromium_problem())
    from playwright.sync_api import sync_playwright
    url, _ = studio
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 1400, "height": 900},
                                      permissions=["clipboard-read", "clipboard-write"])
        page = context.new_page()
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        page.wait_for_function("window.studio && studio.ready && studio.draws > 0", timeout=60000)
        yield page, errors
        browser.close()


def _world_click(page, x: float, y: float) -> None:
    sx, sy = page.evaluate("([x, y]) => { const r = document.getElementById('canvas').getBoundingClientRect();"
                           " return [r.left + studio.view.ox + x * studio.view.s, r.top + studio.view.oy - y * studio.view.s]; }",
                           [x, y])
    page.mouse.click(sx, sy)


# At 4 px/m the view's left edge at x 100 m and its bottom edge at y 60 m, then 40 pans of (7, -4) px: the
# grid's x 30..100 m comes in on the left, y 20..60 m at the bottom; then the same view drawn whole.
# [full redraws during the pans, pixels that differ by more than a quarter of full scale (over white), pixels]
PANNED_VS_FRESH = """() => {
  const c = document.getElementById('canvas'), grab = () => ctx.getImageData(0, 0, c.width, c.height).data;
  studio.view = {s: 4, ox: -4 * 100, oy: c.clientHeight + 4 * 60}; dropLayer(); draw();
  const full = studio.drawn.full;
  for (let i = 0; i < 40; i++) { studio.view.ox += 7; studio.view.oy -= 4; draw(); }
  const panned = grab(), fulls = studio.drawn.full - full;
  dropLayer(); draw();
  const fresh = grab();
  let off = 0;
  for (let i = 0; i < fresh.length; i += 4) {
    let worst = 0;
    for (let k = 0; k < 3; k++) {
      const a = panned[i + k] * panned[i + 3] / 255 + 255 - panned[i + 3], b = fresh[i + k] * fresh[i + 3] / 255 + 255 - fresh[i + 3];
      worst = Math.max(worst, Math.abs(a - b));
    }
    if (worst > 64) off++;
  }
  return [fulls, off, fresh.length / 4];
}"""


@pytest.mark.slow
def test_a_pan_draws_only_the_strips_coming_into_view(page):
    """Panning shifts the network's layer and draws the uncovered strips, never the whole view, and gives
    the picture a whole redraw gives (up to antialiasing along a few lane edges)."""
    page, errors = page
    fulls, off, pixels = page.evaluate(PANNED_VS_FRESH)
    assert fulls == 0 and off < 0.001 * pixels, (fulls, off, pixels)
    assert not errors


@pytest.mark.slow
def test_the_page_in_headless_chromium(page, studio, monkeypatch):
    """Place a window, drop a token and edit it, generate, see the vehicles, keep, ask for sumo-gui (no
    display: the command, quoted, copied); SUMO replays the kept folder."""
    url, out = studio
    page, errors = page
    page.evaluate("([x, y]) => { const c = document.getElementById('canvas'); studio.view = "
                  "{s: 4, ox: c.clientWidth / 2 - 4 * x, oy: c.clientHeight / 2 + 4 * y}; draw(); }", CENTER)
    page.click("#mode-window")
    _world_click(page, *CENTER)
    assert page.evaluate("[studio.win.cx, studio.win.cy]") == pytest.approx(CENTER, abs=0.5)
    page.click("#mode-token")
    _world_click(page, 60.0, 97.6)
    page.wait_for_function("studio.tokens.length === 1")
    assert page.evaluate("studio.tokens[0].lane") == "A1B1_1"
    page.select_option("[data-key=vclass]", "bus")
    page.fill("[data-key=speed]", "6")
    page.press("[data-key=speed]", "Enter")
    page.select_option("[data-key=manoeuvre]", "stop")
    page.wait_for_function("document.getElementById('toml').textContent.includes('stop')")
    toml = page.text_content("#toml")
    assert 'vclass = "bus"' in toml and "speed = 6.0" in toml and 'edge = "A1B1"' in toml
    page.fill("#scenes", "2")
    page.click("#generate")          # busy from the click until the server answers, either way
    page.wait_for_function("!studio.busy", timeout=180000)
    result = page.evaluate("studio.result")
    assert result and len(result["scenes"]) == 2, page.text_content("#gen-status")
    assert page.evaluate("studio.drawn.boxes") == len(result["scenes"][0]["agents"]) > 0
    assert page.evaluate("document.querySelectorAll('#multiples canvas').length") == 2
    assert any(a["source"] == "user" for a in result["scenes"][0]["agents"])
    if os.environ.get("STUDIO_SCREENSHOT"):
        page.screenshot(path=os.environ["STUDIO_SCREENSHOT"])
    page.fill("#keep-name", "from_the_page")
    page.click("#keep")
    page.wait_for_function("!studio.busy", timeout=60000)
    folder = os.path.join(out, "from_the_page")
    assert page.evaluate("studio.kept && studio.kept.folder") == os.path.abspath(folder), page.text_content("#keep-status")

    _no_display(monkeypatch)
    page.click("#open-gui")
    page.wait_for_function("!studio.busy")
    cfg = os.path.abspath(os.path.join(folder, "scenario.sumocfg"))
    assert page.evaluate("studio.gui.launched") is False and "no display" in page.text_content("#gui-status")
    command = page.text_content("#gui-command")
    assert shlex.split(command) == ["sumo-gui", "-c", cfg]
    page.click("#gui-copy")
    page.wait_for_function("studio.copied !== undefined")
    assert page.evaluate("navigator.clipboard.readText()") == command
    assert not errors
    assert open(os.path.join(folder, "tokens.toml")).read() == result["tokens"]
    _replays(folder)


def test_the_command_line(tmp_path):
    """Bad flags are one line and exit 2; the server prints its address."""
    bad = subprocess.run([sys.executable, "-m", "sumo_scendiff.studio", "-n", "x.sumocfg"], capture_output=True,
                         text=True, cwd=ROOT)
    assert bad.returncode == 2 and "-n: x.sumocfg: a SUMO configuration" in bad.stderr
    steps = subprocess.run([sys.executable, "-m", "sumo_scendiff.studio", "-n", "x.net.xml", "--steps", "0"],
                           capture_output=True, text=True, cwd=ROOT)
    assert steps.returncode == 2 and "--steps must be at least 1, got 0" in steps.stderr
    missing = subprocess.run([sys.executable, "-m", "sumo_scendiff.studio", "-n", str(tmp_path / "no.net.xml"),
                              "-o", str(tmp_path / "o")], capture_output=True, text=True, cwd=ROOT)
    assert missing.returncode == 2 and "no.net.xml" in missing.stderr and "Traceback" not in missing.stderr
    shutil.rmtree(tmp_path / "o", ignore_errors=True)
