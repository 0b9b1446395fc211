"""Starting SUMO for seeding: libsumo in-process (fast, one simulation per process) or traci
connected to ``sumo-gui`` (to watch), the same options either way.

    sim = start(SimConfig(net="networks/city.net.xml"))       # the libsumo module, started
    sim.simulationStep(); ...; sim.close()

Options the seeded scenes rely on: the sublane model (``--lateral-resolution``) so generated agents
keep their lateral offset in the lane, junction collision checks, and a short step (0.5 s: a
vehicle at 15 m/s moves 7.5 m per step; SUMO's 1 s default hides emergency braking).
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field

from ..core.tools import sumo_binary


class SimError(RuntimeError):
    """SUMO refused to start (bad route file, ...): the message is SUMO's first error line."""


# what the seeding needs SUMO to do as it does (a scenario's own value is not carried)
OWN_OPTIONS = frozenset({"step-length", "seed", "no-step-log", "duration-log.disable", "collision.check-junctions",
                         "save-state.precision", "lateral-resolution", "begin", "end", "net-file", "route-files",
                         "additional-files", "load-state", "no-warnings", "start", "quit-on-end", "mesosim"})


@dataclass
class SimConfig:
    net: str
    routes: tuple[str, ...] = ()
    additional: tuple[str, ...] = ()    # vTypes, TLS programs, detectors, stops (-a)
    step_length: float = 0.5
    lateral_resolution: float = 0.8     # sublane model; 0 = off (agents snap to lane centres)
    check_junctions: bool = True        # collisions inside junctions count too
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

    def args(self) -> list[str]:
        """Command line (without the binary); also what ``scenario.sumocfg`` repeats."""
        theirs = {name: value for name, value in self.scenario_options if name not in OWN_OPTIONS}
        a = ["-n", os.path.abspath(self.net), "--step-length", f"{self.step_length:g}",
             "--seed", str(self.seed), "--no-step-log", "true", "--duration-log.disable", "true",
             "--collision.check-junctions", "true" if self.check_junctions else "false",
             "--time-to-teleport", theirs.pop("time-to-teleport", "300"), "--save-state.precision", "6"]
        for name, value in theirs.items():
            a += [f"--{name}", value]
        if self.lateral_resolution > 0:
            a += ["--lateral-resolution", f"{self.lateral_resolution:g}"]
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
            import traci
            binary = sumo_binary("sumo-gui") if cfg.gui else sumo_binary("sumo")
            traci.start([binary] + args + (["--start"] if cfg.gui else []))
            return traci
        return _start_libsumo(args)
    except SimError:
        raise
    except Exception as e:  # traci's FatalTraCIError: SUMO printed the cause
        msg = str(e).strip().splitlines()
        raise SimError(msg[-1] if msg else f"SUMO failed to start ({type(e).__name__})") from None


def _start_libsumo(args: list[str]):
    """libsumo, started in-process; what SUMO writes to the terminal while loading (its process's
    stderr) is caught, so that a refusal is one line: SUMO's first error."""
    import tempfile

    import libsumo
    with tempfile.TemporaryFile(mode="w+", errors="replace") as caught:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(caught.fileno(), 2)
        try:
            libsumo.start([sumo_binary("sumo")] + args)
        except Exception as e:  # libsumo.TraCIException: "Process Error"; the cause is in what SUMO wrote
            os.dup2(saved, 2)
            caught.seek(0)
            errors = [ln.strip() for ln in caught if ln.startswith("Error:")]
            cause = errors[0].removeprefix("Error:").strip() if errors else str(e).strip() or type(e).__name__
            raise SimError(f"SUMO refused to start: {cause}") from None
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        caught.seek(0)
        for line in caught:          # its warnings (when not --no-warnings) still reach the terminal
            sys.stderr.write(line)
    return libsumo


def start_config(path: str):
    """libsumo on a ``.sumocfg`` the product wrote (a folder's portable start), quiet, its additional
    files' outputs going nowhere (sim.additional)."""
    from .additional import quiet_outputs
    from .scenario import scenario_from_files
    extra = scenario_from_files(config=path).additional
    return _start_libsumo(["-c", path, "--no-step-log", "true", "--no-warnings", "true"]
                          + (["-a", ",".join(quiet_outputs(extra))] if extra else []))


def close(sim) -> None:
    try:
        sim.close()
    except Exception:  # already closed (sumo-gui window closed by the user)
        pass
