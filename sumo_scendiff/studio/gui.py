"""Open a kept scene in sumo-gui: started on this machine's display where there is one, otherwise the
command to run, shell-quoted, for the page to show (docs/studio.md, "Keep")."""
from __future__ import annotations

import os
import shlex
import subprocess
import threading

from ..core.tools import sumo_binary
from ..sim.sumo import has_display

# sumo-gui that cannot open its display exits at once (FOX: "unable to open display"); one still running
# after this long has opened its window
GUI_CHECK_S = 3.0


def gui_args(cfg: str) -> list[str]:
    """What is started: sumo-gui on the scenario, the path one argument whatever its characters."""
    return [sumo_binary("sumo-gui"), "-c", cfg]


def gui_command(cfg: str) -> str:
    """The same as a line for a shell (sumo-gui from the PATH, the path quoted)."""
    return shlex.join(["sumo-gui", "-c", cfg])


def open_in_gui(studio, body) -> dict:
    """Start sumo-gui on a kept scene, detached from the server, where there is a display: ``launched``
    says whether it did; ``command`` is always the line to run it by hand, ``why`` why it was not started."""
    folder = studio.kept_folder(body.get("name") if isinstance(body, dict) else None)
    cfg = os.path.join(folder, "scenario.sumocfg")
    answer = {"launched": False, "command": gui_command(cfg), "config": cfg}
    if not has_display():
        return {**answer, "why": "no display here (DISPLAY is not set): run the command where there is one"}
    log = os.path.join(studio.drafts, f"sumo-gui-{os.path.basename(folder)}.log")
    with open(log, "wb") as err:
        try:
            proc = subprocess.Popen(gui_args(cfg), cwd=folder, stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        except OSError as e:
            return {**answer, "why": f"sumo-gui did not start: {e.strerror}"}
    try:
        code = proc.wait(timeout=GUI_CHECK_S)
    except subprocess.TimeoutExpired:
        threading.Thread(target=proc.wait, daemon=True).start()   # reaped when the user closes it
        return {**answer, "launched": True, "pid": proc.pid}
    with open(log, errors="replace") as f:
        lines = [ln.strip() for ln in f if ln.strip()]
    return {**answer, "why": f"sumo-gui exited ({code}): {lines[-1] if lines else 'no message'}"}
