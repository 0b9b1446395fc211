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
