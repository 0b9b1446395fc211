"""What the command-line modules share (core/cli.py)."""
from __future__ import annotations

import pytest

from sumo_scendiff.core.cli import joined


@pytest.mark.parametrize("form", ["split", "joined"])
def test_a_negative_coordinate_is_a_value_not_a_flag(form, tmp_path):
    """fill --area and run --center take values that begin with a minus (networks with negative
    coordinates), given as two words or with '='; other flags are left to argparse."""
    from sumo_scendiff.fill.__main__ import get_options as fill_options
    from sumo_scendiff.run import get_options as run_options
    area = ["--area", "-100,-50,300,350"] if form == "split" else ["--area=-100,-50,300,350"]
    o = fill_options(["-n", "x.net.xml", *area, "-o", str(tmp_path / "f")])
    assert o.area == (-100.0, -50.0, 300.0, 350.0)
    center = ["--center", "-5.5,3"] if form == "split" else ["--center=-5.5,3"]
    o = run_options(["-n", "x.net.xml", *center, "-b", "60", "-o", str(tmp_path / "r")])
    assert o.center == "-5.5,3" and o.begin == 60.0


def test_only_coordinate_flags_are_joined():
    import argparse
    p = argparse.ArgumentParser()
    p.add_argument("--center", metavar="X,Y")
    p.add_argument("--seed", type=int)
    p.add_argument("-v", action="store_true")
    assert joined(p, ["--center", "-.5,2", "--seed", "-3", "-v"]) == ["--center=-.5,2", "--seed", "-3", "-v"]
    assert joined(p, ["--center", "-v"]) == ["--center", "-v"]     # a flag after it stays a flag
    with pytest.raises(SystemExit):
        p.parse_args(joined(p, ["--center", "-v"]))


def test_run_turns_a_center_window_by_yaw(capsys):
    """run --center X,Y --yaw RAD: the window turned (a negative angle is a value too); --yaw alone
    or not finite is one line and exit 2."""
    from sumo_scendiff.run import get_options as run_options
    assert run_options(["-n", "x.net.xml", "--center", "5,3", "--yaw", "-0.5"]).yaw == -0.5
    for bad, says in ((["--yaw", "1"], "--yaw: turns a --center window"),
                      (["--center", "5,3", "--yaw", "nan"], "--yaw must be a finite angle")):
        with pytest.raises(SystemExit) as e:
            run_options(["-n", "x.net.xml", *bad])
        err = capsys.readouterr().err
        assert e.value.code == 2 and says in err.strip().splitlines()[-1]


def _scendiff(*args):
    """The installed ``scendiff`` console script (pyproject's [project.scripts])."""
    import shutil
    import subprocess
    exe = shutil.which("scendiff")
    assert exe, "scendiff is not installed: pip install -e ."
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=300)


def test_the_scendiff_command_dispatches_to_each_tool(tmp_path):
    """scendiff TOOL runs python -m sumo_scendiff.TOOL: its help, its one-line errors and exit 2;
    an unknown tool is one line and exit 2 too."""
    from sumo_scendiff.console import TOOLS
    assert {"run", "fill", "sweep", "evaluate", "train", "studio"} <= set(TOOLS)
    top = _scendiff("--help")
    assert top.returncode == 0 and all(t in top.stdout for t in TOOLS)
    helped = _scendiff("run", "--help")
    assert helped.returncode == 0 and "--net-file" in helped.stdout and "--tokens" in helped.stdout
    missing = str(tmp_path / "missing.net.xml")
    bad = _scendiff("run", "-n", missing, "-o", str(tmp_path / "out"))
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and missing in bad.stderr, bad.stderr
    assert not (tmp_path / "out").exists()
    fill = _scendiff("fill", "--help")
    assert fill.returncode == 0 and "--density" in fill.stdout
    unknown = _scendiff("runn")
    assert unknown.returncode == 2 and unknown.stderr.strip().splitlines() == [
        unknown.stderr.strip()] and "'runn'" in unknown.stderr
