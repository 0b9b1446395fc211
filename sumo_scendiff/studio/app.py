"""The studio's web server: the page, its assets and the JSON endpoints (docs/studio.md)."""
from __future__ import annotations

import itertools
import json
import os
import threading
from functools import cached_property

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from . import generate as gen
from .geometry import StudioError, fill_density, geometry, snap
from .gui import open_in_gui
from .tokenfile import token_toml

STATIC = os.path.join(os.path.dirname(__file__), "static")
MAX_BODY = 64 * 2 ** 20   # a fill.json of a whole city is tens of MB


class Studio:
    """What the server knows: the inputs of its command line and its output directory."""

    def __init__(self, net: str | None, config: str | None, out: str, checkpoint: str | None = None,
                 steps: int | None = None):
        from ..map.network import Network
        from ..sim.scenario import scenario_from_files
        self.scenario = scenario_from_files(config, net)
        # held for the server's life: every run inside it is handed these instead of reading them
        # again (Network.load, ScenarioGenerator.load: what this process holds); the model at first use
        self.net = Network.load(self.scenario.net)
        self.checkpoint, self.generator = checkpoint, None
        self._hold = threading.Lock()
        self.warm = threading.Event()    # set once the background warm-up (make_app) is done
        self.inputs = (["-c", config] if config else []) + (["-n", net] if net else []) + \
            (["--checkpoint", checkpoint] if checkpoint else []) + (["--steps", str(steps)] if steps else [])
        self.out = out
        self.drafts = os.path.join(out, ".drafts")
        os.makedirs(self.drafts, exist_ok=True)
        self._count = itertools.count(len(os.listdir(self.drafts)))
        self._new = threading.Lock()

    def hold_model(self):
        """The model of this server's generations, loaded once (threads set first, as run does)."""
        with self._hold:
            if self.generator is None:
                from ..core.threads import GENERATION_THREADS, share_cpu
                share_cpu(default=GENERATION_THREADS)   # before torch is imported (core/threads.py)
                from ..generation.generator import ScenarioGenerator
                self.generator = ScenarioGenerator.load(self.checkpoint)
            return self.generator

    @property
    def name(self) -> str:
        return self.net.name

    @cached_property
    def geometry_json(self) -> bytes:
        doc = geometry(self.net)
        doc.update(config=self.scenario.config, out=os.path.abspath(self.out), demand=bool(self.scenario.routes))
        return json.dumps(doc, separators=(",", ":")).encode()

    def new_draft(self) -> str:
        with self._new:
            while True:
                path = os.path.join(self.drafts, f"gen-{next(self._count):04d}")
                if not os.path.exists(path):
                    os.makedirs(path)
                    return path

    def kept_folder(self, name) -> str:
        """The folder ``-o/NAME`` of a kept scene (only there: the server opens nothing else)."""
        if not (isinstance(name, str) and gen.NAME.fullmatch(name)):
            raise StudioError("open: expected the name of a kept folder (letters, digits, _ . -)")
        folder = os.path.abspath(os.path.join(self.out, name))
        if not os.path.isfile(os.path.join(folder, "scenario.sumocfg")):
            raise StudioError(f"open: {name}: no kept scene of that name in {self.out}")
        return folder

    def fill_path(self, path) -> str:
        """A fill.json the page names: only under -o (the server reads nothing else it is not given)."""
        if not isinstance(path, str) or not path:
            raise StudioError("fill: expected a path under the output directory")
        full = os.path.realpath(os.path.join(self.out, path))
        root = os.path.realpath(self.out)
        if os.path.commonpath([full, root]) != root or not os.path.isfile(full):
            raise StudioError(f"fill: {path}: no such file under the output directory {self.out}")
        return full


async def _body(request: Request):
    raw = await request.body()
    if len(raw) > MAX_BODY:
        raise StudioError(f"request body over {MAX_BODY // 2 ** 20} MB")
    try:
        return json.loads(raw or b"null")
    except (ValueError, UnicodeDecodeError) as e:
        raise StudioError(f"not JSON ({e})") from None


def _endpoint(fn, status_ok: int = 200):
    """A POST handler taking the JSON body; a refused request is a 4xx with one line, never a traceback."""
    async def handler(request: Request):
        try:
            body = await _body(request)
            return JSONResponse(await run_in_threadpool(fn, request.app.state.studio, body), status_ok)
        except FileExistsError as e:
            return JSONResponse({"error": str(e)}, 409)
        except StudioError as e:
            return JSONResponse({"error": str(e)}, 400)
    return handler


def _fill(studio: Studio, body) -> dict:
    if isinstance(body, dict) and "path" in body:
        with open(studio.fill_path(body["path"])) as f:
            try:
                doc = json.load(f)
            except ValueError as e:
                raise StudioError(f"fill: {body['path']}: not JSON ({e})") from None
    else:
        doc = body.get("fill") if isinstance(body, dict) else None
    return fill_density(studio.net, doc)


async def _index(request):
    return FileResponse(os.path.join(STATIC, "index.html"))


async def _geometry(request):
    return Response(request.app.state.studio.geometry_json, media_type="application/json")


async def _not_found(request, exc):
    return JSONResponse({"error": f"{request.url.path}: {getattr(exc, 'detail', 'not found')}"},
                        getattr(exc, "status_code", 404))


async def _server_error(request, exc):
    # one line, no traceback to the page (the server's log keeps it)
    return JSONResponse({"error": f"{type(exc).__name__}: {exc}"}, 500)


def _warm_up(studio: Studio) -> None:
    """Load the model and import what a generation needs (torch, run, SUMO's session) while the user
    places a window and tokens: the first generation then does only run's own work (docs/studio.md,
    "Speed"). ``studio.warm`` is set when done."""
    try:
        studio.hold_model()
        from .. import run  # noqa: F401
        from ..sim.session import Session  # noqa: F401
    except Exception:   # a broken install or checkpoint: the generation reports it, in its one line
        pass
    finally:
        studio.warm.set()


def make_app(net: str | None, config: str | None, out: str, checkpoint: str | None = None,
             steps: int | None = None, warm: bool = True) -> Starlette:
    """The studio's app; ``warm`` loads the model and imports the generation's modules in the background
    from the start."""
    routes = [Route("/", _index), Route("/api/network", _geometry),
              Route("/api/snap", _endpoint(lambda s, b: snap(s.net, b if isinstance(b, dict) else {})),
                    methods=["POST"]),
              Route("/api/tokens", _endpoint(lambda s, b: {"toml": token_toml(b)}), methods=["POST"]),
              Route("/api/generate", _endpoint(gen.generate), methods=["POST"]),
              Route("/api/keep", _endpoint(gen.keep, 201), methods=["POST"]),
              Route("/api/fill", _endpoint(_fill), methods=["POST"]),
              Route("/api/open", _endpoint(open_in_gui), methods=["POST"]),
              Mount("/static", StaticFiles(directory=STATIC))]
    app = Starlette(routes=routes, exception_handlers={404: _not_found, 405: _not_found, 500: _server_error})
    app.state.studio = Studio(net, config, out, checkpoint, steps)
    if warm:
        threading.Thread(target=_warm_up, args=(app.state.studio,), name="studio-warm-up", daemon=True).start()
    return app
