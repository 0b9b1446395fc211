"""Starting SUMO for seeding: libsumo in-process (fast, one simulation per process) or traci
connected to ``sumo-gui`` (to watch), the same options either way.

    sim = start(SimConfig(net="networks/city.net.xml"))       # the libsumo module, started
    sim.simulationStep(); ...; sim.close()

The user's scenario runs with its own settings: its step length (SUMO's default where its
configuration names none, :func:`step_length_for`), its lane-change model (the sublane model only
where it sets ``lateral-resolution``) and every option it carries (``SumoScenario.options``). The
seeding adds :data:`ADDED_OPTIONS` (a scenario's own value of one wins; ``seeding_options=False``
leaves them out) and quiets SUMO's console (:data:`QUIET_OPTIONS`); docs/sumo-options.md says why.
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
from dataclasses import dataclass, field

from ..core.tools import sumo_binary
from .additional import NULL


class SimError(RuntimeError):
    """SUMO refused to start (bad route file, ...): the message is SUMO's first error line."""


class SumoDied(SimError):
    """The SUMO process of a traci simulation ended in the middle of it (killed, crashed, closed by
    someone else); the one-line message holds its last words (:func:`last_words`). What the
    co-simulation API raises for it; the commands end on it in one line, exit 2."""


CONNECT_TRIES = 1200        # traci connection tries 50 ms apart while SUMO loads (a minute)
PRODUCT_STEP_LENGTH = 0.5   # s: a bare network's step, where no scenario gives one (docs/sumo-options.md)
SUMO_STEP_LENGTH = 1.0      # s: SUMO's own default --step-length

# what the seeding adds to a scenario's options (docs/sumo-options.md says why); the scenario's own
# value of one wins, SimConfig(seeding_options=False) (the CLIs' --no-seeding-options) leaves them out
ADDED_OPTIONS = {"collision.check-junctions": "true", "save-state.precision": "6"}
# what a saved state holds, on every run (the warm-up's, the seeding's, the exported configurations'):
# SUMO leaves persons and containers out of a state unless asked, and a scene started from it would lose
# the pedestrians and passengers on the road at --begin; no difference in what SUMO simulates
STATE_OPTIONS = {"save-state.transportables": "true"}
# SUMO's console kept quiet: no difference in what it simulates
QUIET_OPTIONS = {"no-step-log": "true", "duration-log.disable": "true"}
# a device's output SUMO writes where it runs without being asked: an SSM device (device.ssm.*, a vType's
# has.ssm.device) writes ssm_<vehicle>.xml into the working directory unless given a file, and every run of
# the product (warm-up, seeding, each scene) wrote and overwrote them where its user ran it; a scenario's
# outputs are its user's business (sim.scenario), these are discarded as those are left out
DEVICE_OUTPUTS = {"device.ssm.file": NULL}
# and its warnings too, for a SUMO that only loads, checks or replays what was already reported
SILENT_OPTIONS = {**QUIET_OPTIONS, "no-warnings": "true"}
# the product's own, never a scenario's: the inputs and time window it builds and the seed of its -s
OWN_OPTIONS = frozenset({"step-length", "seed", "begin", "end", "net-file", "route-files", "additional-files",
                         "load-state", "no-warnings", "start", "quit-on-end"})


def as_args(options: dict[str, str]) -> list[str]:
    """SUMO options name -> value as command-line arguments."""
    return [a for name, value in options.items() for a in (f"--{name}", value)]


def step_length_for(scen, given: float | None = None) -> float:
    """The step a run of scenario ``scen`` (sim.scenario.SumoScenario) uses: ``given`` (the user's
    --step-length), else its configuration's, else SUMO's default where there is a user scenario
    (a configuration or a demand: its authors ran it so), else the product's for a bare network."""
    if given is not None:
        return given
    return scen.step_length or default_step_length(bool(scen.config or scen.routes))


def default_step_length(scenario: bool) -> float:
    """SUMO's default step for a user's scenario (``scenario``: a configuration or a demand),
    the product's for a bare network."""
    return SUMO_STEP_LENGTH if scenario else PRODUCT_STEP_LENGTH


@dataclass
class SimConfig:
    """One SUMO run as the product starts it. Its fields are the library's defaults: a bare
    network's step (:data:`PRODUCT_STEP_LENGTH`) whatever ``routes`` holds; the CLIs and sweeps
    pass the scenario's own (:func:`step_length_for`, :func:`settings`), as a library caller with a
    user's scenario should (docs/sumo-options.md)."""
    net: str
    routes: tuple[str, ...] = ()
    additional: tuple[str, ...] = ()    # vTypes, TLS programs, detectors, stops (-a)
    step_length: float = PRODUCT_STEP_LENGTH
    # the sublane model (m): None, the scenario's own lateral-resolution (none: off); 0 off; > 0 on
    lateral_resolution: float | None = None
    seeding_options: bool = True        # ADDED_OPTIONS (a scenario's own value of one wins)
    gui: bool = False                   # sumo-gui through traci instead of libsumo
    traci: bool = False                 # sumo through traci (a separate process) instead of libsumo
    seed: int = 0
    begin: float | None = None          # simulation start (s): a demand's first departure
    # a saved state SUMO starts from (--load-state; it begins at the state's time). Loaded so, not by
    # simulation.loadState after the start: that re-inserts a flow whose vehicles have all departed
    # (the state no longer holds it, the route file does), from the from/via/to its state kept as a route
    state: str | None = None
    extra: tuple[str, ...] = field(default_factory=tuple)
    # a scenario's own options on how SUMO runs its demand (SumoScenario.options): carried, but for
    # those the product sets itself (:data:`OWN_OPTIONS`)
    scenario_options: tuple[tuple[str, str], ...] = ()

    def run_options(self) -> dict[str, str]:
        """The options on how SUMO runs, name -> value: ours (:data:`STATE_OPTIONS`, :data:`ADDED_OPTIONS`,
        the sublane model asked for) under the scenario's own, which win."""
        theirs = {name: value for name, value in self.scenario_options if name not in OWN_OPTIONS}
        if self.lateral_resolution is not None:       # the user's flag over the scenario's setting
            theirs.pop("lateral-resolution", None)
            if self.lateral_resolution > 0:
                theirs["lateral-resolution"] = f"{self.lateral_resolution:g}"
        return {**QUIET_OPTIONS, **STATE_OPTIONS, **DEVICE_OUTPUTS, **(ADDED_OPTIONS if self.seeding_options else {}),
                **theirs}

    def args(self) -> list[str]:
        """Command line (without the binary); also what ``scenario.sumocfg`` repeats."""
        a = ["-n", os.path.abspath(self.net), "--step-length", f"{self.step_length:g}", "--seed", str(self.seed)]
        a += as_args(self.run_options())
        if self.routes:
            a += ["-r", ",".join(os.path.abspath(r) for r in self.routes)]
        if self.additional:
            a += ["-a", ",".join(os.path.abspath(f) for f in self.additional)]
        if self.state is not None:
            a += ["--load-state", os.path.abspath(self.state)]
        elif self.begin is not None:
            a += ["-b", f"{self.begin:g}"]
        return a + list(self.extra)

    def options(self) -> dict[str, str]:
        """The options as a name -> value dict (for writing a .sumocfg)."""
        a = self.args()
        return {a[i].lstrip("-"): a[i + 1] for i in range(0, len(a) - 1, 2)}


def add_arguments(p) -> None:
    """The CLIs' (run, fill) flags on how SUMO runs a scenario (:func:`settings` reads them)."""
    p.add_argument("--step-length", type=float, default=None, metavar="S",
                   help="SUMO's step (s); default: the configuration's (-c), else SUMO's 1 s with a scenario "
                        f"(-c/-r), else {PRODUCT_STEP_LENGTH:g} on a bare network")
    p.add_argument("--lateral-resolution", type=float, default=None, metavar="M",
                   help="SUMO's sublane model at this resolution (m; 0: off); default: the scenario's own "
                        "(off where it sets none)")
    p.add_argument("--no-seeding-options", dest="seeding_options", action="store_false",
                   help="leave out the options the seeding adds (" + ", ".join(ADDED_OPTIONS)
                        + "): SUMO runs with the scenario's options and its own defaults")
    p.add_argument("--model-fleet", action="store_true",
                   help="seed each vehicle the model draws with its drawn size on SUMO's default vType, "
                        "as without a demand, not as one of the scenario's own vTypes (a token's vtype "
                        "and a demand vehicle's own type are still theirs)")


def settings_problem(o) -> str | None:
    """What is wrong with the flags of :func:`add_arguments` (one line), or None."""
    if o.step_length is not None and not o.step_length > 0:
        return f"--step-length must be > 0, got {o.step_length:g}"
    if o.lateral_resolution is not None and not o.lateral_resolution >= 0:
        return f"--lateral-resolution must be >= 0 (0: off), got {o.lateral_resolution:g}"
    return None


def settings(o, scen, mesoscopic: bool = True) -> dict:
    """SimConfig's keyword arguments on how SUMO runs, from the flags of :func:`add_arguments` and
    the user's scenario (its step length, its options); without ``mesoscopic`` (the fill's) its
    mesoscopic model is left out (:func:`microscopic`)."""
    options = scen.options if mesoscopic else microscopic(scen.options)
    return {"step_length": step_length_for(scen, o.step_length), "scenario_options": options,
            "lateral_resolution": o.lateral_resolution, "seeding_options": o.seeding_options}


def mesoscopic_options(options: tuple[tuple[str, str], ...]) -> tuple[tuple[str, str], ...]:
    """Those of a scenario's options (name, value) that set SUMO's mesoscopic model (its configuration
    section ``mesoscopic``: mesosim, meso-edgelength, ...), however the configuration filed them."""
    from ..core.tools import sumo_option_sections
    sections = sumo_option_sections()
    return tuple((n, v) for n, v in options if sections.get(n) == "mesoscopic")


def microscopic(options: tuple[tuple[str, str], ...]) -> tuple[tuple[str, str], ...]:
    """A scenario's options without those of its mesoscopic model (:func:`mesoscopic_options`)."""
    meso = set(mesoscopic_options(options))
    return tuple(o for o in options if o not in meso)


def mesoscopic(sim) -> bool:
    """Whether simulation ``sim`` runs SUMO's mesoscopic model (``--mesosim``)."""
    from ..core.sumo_xml import boolean
    try:
        return bool(boolean(sim.simulation.getOption("mesosim")))
    except Exception:  # SUMO < 1.19 has no getOption
        return False


def has_display() -> bool:
    """Whether a GUI can open: sumo-gui without one retries its display connection forever."""
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY")
                                                        or os.environ.get("WAYLAND_DISPLAY"))


def start(cfg: SimConfig, quiet: bool = True):
    """Start SUMO and return the module to drive it (``libsumo``, or ``traci`` for the GUI). The
    additional files' outputs (detectors, edgeData, ...) go nowhere: they are the user's, to be
    written by the user's runs, not beside their files by ours (sim.additional)."""
    from dataclasses import replace

    from .additional import quiet_outputs
    cfg = replace(cfg, additional=quiet_outputs(cfg.additional))
    args = cfg.args() + (["--no-warnings", "true"] if quiet else [])
    if cfg.gui and not has_display():
        raise SimError("--gui: no display to open sumo-gui on (DISPLAY is not set); run without --gui "
                       "and open the exported scenario.sumocfg where there is a screen")
    try:
        if cfg.gui or cfg.traci:
            return _start_traci([sumo_binary("sumo-gui") if cfg.gui else sumo_binary("sumo")] + args
                                + (["--start"] if cfg.gui else []))
        return _start_libsumo(args)
    except SimError:
        raise
    except Exception as e:  # traci's FatalTraCIError: SUMO printed the cause
        msg = str(e).strip().splitlines()
        raise SimError(msg[-1] if msg else f"SUMO failed to start ({type(e).__name__})") from None


def _start_traci(cmd: list[str]):
    """``cmd`` as a process of its own driven through traci (as traci.start does), its console
    output kept in a temporary file: its first error if it refuses to start, its last words if it
    ends in the middle (:func:`last_words`)."""
    import subprocess
    import tempfile

    import traci
    from sumolib.miscutils import getFreeSocketPort

    from ..core.sumo_log import first_error
    log = tempfile.NamedTemporaryFile(prefix="scendiff-sumo-", suffix=".log", delete=False)
    port = getFreeSocketPort()
    proc = subprocess.Popen(cmd + ["--remote-port", str(port)], stdout=log, stderr=subprocess.STDOUT)
    proc.console = log.name        # read by last_words, removed by close
    try:   # traci.init, polling every 50 ms rather than each second, without its "Retrying" lines
        with contextlib.redirect_stdout(io.StringIO()):
            traci.connect(port, numRetries=CONNECT_TRIES, proc=proc, waitBetweenRetries=0.05, label="default")
        traci.switch("default")
    except Exception:              # traci's FatalTraCIError: SUMO stopped while loading
        proc.wait()
        with open(log.name, errors="replace") as f:
            cause = first_error(f.read())
        os.remove(log.name)
        raise SimError(f"SUMO refused to start: {cause}" if cause else
                       f"SUMO (process {proc.pid}) ended while loading: {_how(proc.returncode)}") from None
    return traci


def _how(code: int) -> str:
    """How a process ended, from its exit code (a negative one: the signal that killed it)."""
    import signal
    if code < 0 and -code in signal.Signals._value2member_map_:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit code {code}"


def _process(sim):
    """The SUMO process of a traci connection (None for libsumo, or a connection without one)."""
    try:   # the traci module (its current connection, labelled or not) or a traci Connection
        conn = sim.getConnection(sim.getLabel()) if hasattr(sim, "getLabel") else sim
        return conn._process
    except Exception:
        return None


def last_words(sim, wait_s: float = 2.0) -> str:
    """How the SUMO of traci connection ``sim`` ended, in one line: the signal that killed it or its
    exit code, and its last console line where the product started it (sim.sumo.start)."""
    import subprocess
    proc = _process(sim)
    if proc is None:
        return "its connection was closed"
    try:
        code = proc.wait(timeout=wait_s)
    except subprocess.TimeoutExpired:
        return f"process {proc.pid} closed the connection and still runs"
    said = ""
    if getattr(proc, "console", None) and os.path.exists(proc.console):
        with open(proc.console, errors="replace") as f:
            lines = [ln.strip() for ln in f.read().splitlines() if ln.strip()]
        said = f"; its last words: {lines[-1]}" if lines else "; it said nothing"
    return f"SUMO (process {proc.pid}) ended in the middle of the simulation: {_how(code)}{said}"


def died(e: BaseException, sim) -> SumoDied | None:
    """``e`` as :class:`SumoDied` where it is traci's word that SUMO is gone, else None."""
    return SumoDied(last_words(sim)) if type(e).__name__ == "FatalTraCIError" else None


_TERMINAL: list = []     # the stderr faulthandler writes to, kept open


def _start_libsumo(args: list[str]):
    """libsumo, started in-process; what SUMO writes to the terminal while loading (its process's
    stderr) is caught, so that a refusal is one line: SUMO's first error; its warnings (when not
    --no-warnings) still reach the terminal, each kind once with its count (core.sumo_log)."""
    import faulthandler

    import libsumo

    from ..core.sumo_log import caught_stderr, echo, first_error
    from .state import in_process_state
    if "--load-state" in args:
        at = args.index("--load-state") + 1
        args = args[:at] + [in_process_state(args[at])] + args[at + 1:]
    if not faulthandler.is_enabled():   # SUMO crashing in-process says so on stderr, not exit 139 alone;
        _TERMINAL.append(os.fdopen(os.dup(2), "w"))   # a copy of it: caught_stderr takes fd 2 while SUMO loads
        faulthandler.enable(_TERMINAL[0])
    with caught_stderr() as text:
        try:
            libsumo.start([sumo_binary("sumo")] + args)
        except Exception as e:  # libsumo.TraCIException: "Process Error"; the cause is in what SUMO wrote
            cause = first_error(text()) or str(e).strip() or type(e).__name__
            raise SimError(f"SUMO refused to start: {cause}") from None
        said = text()
    echo(said)
    return libsumo


def start_config(path: str):
    """libsumo on a ``.sumocfg`` the product wrote (a folder's portable start), quiet, its additional
    files' outputs going nowhere (sim.additional)."""
    from .additional import quiet_outputs
    from .scenario import scenario_from_files
    from sumolib.options import readOptions
    extra = scenario_from_files(config=path).additional
    # its state given again on the command line (which wins), so that libsumo loads the copy it survives
    state = [os.path.join(os.path.dirname(os.path.abspath(path)), o.value)
             for o in readOptions(path) if o.name == "load-state"]
    return _start_libsumo(["-c", path, *as_args(SILENT_OPTIONS)]
                          + (["-a", ",".join(quiet_outputs(extra))] if extra else [])
                          + (["--load-state", state[0]] if state else []))


def close(sim) -> None:
    proc = _process(sim)
    try:
        sim.close()
    except Exception:  # already closed (sumo-gui window closed by the user)
        pass
    if getattr(proc, "console", None):
        with contextlib.suppress(OSError):
            os.remove(proc.console)
