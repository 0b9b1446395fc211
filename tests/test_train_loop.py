"""The exponential moving average of the weights (train_loop.EMA)."""
from __future__ import annotations

import pytest
import torch
from torch import nn

from sumo_scendiff.train.loop import EMA


def test_half_life_and_its_ramp_up():
    ema = EMA(nn.Linear(2, 2), halflife=100, rampup=0.05)
    assert ema.beta(10_000) == pytest.approx(0.5 ** (1 / 100))   # the half-life once ramped up
    assert ema.beta(200) == pytest.approx(0.5 ** (1 / 10))       # 5 % of the 200 steps so far
    assert EMA(nn.Linear(2, 2), halflife=100, rampup=0).beta(1) == pytest.approx(0.5 ** (1 / 100))


def test_average_halves_its_distance_in_one_half_life():
    net = nn.Linear(3, 1)
    ema = EMA(net, halflife=20, rampup=0)
    start = ema.model.weight.detach().clone()
    with torch.no_grad():
        net.weight.add_(1.0)
    for step in range(1, 21):  # the trained weights stay 1 away: after 20 steps the average is half-way
        ema.update(net, step)
    torch.testing.assert_close(ema.model.weight, start + 0.5)
    assert not ema.model.weight.requires_grad  # the average is never trained itself


def test_bad_stage_input_raises_and_the_cli_says_one_line(tmp_path):
    """Library code raises TrainError; the train CLI turns it into one line and exit 2."""
    import subprocess
    import sys

    from sumo_scendiff.train.__main__ import get_options
    from sumo_scendiff.train.loop import TrainError
    from sumo_scendiff.train.stages import train_autoencoder
    out = str(tmp_path / "ae")
    for extra, says in ((["--freeze-encoder"], "--freeze-encoder needs --init-from"),
                        (["--model-config", '{"C_t": 3}'], "--model-config: C_t 3")):
        with pytest.raises(TrainError, match=says):
            train_autoencoder(get_options(["autoencoder", "--data", str(tmp_path), "-o", out, *extra]))
    p = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "autoencoder", "--data", str(tmp_path),
                        "-o", out, "--freeze-encoder"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and p.stderr.strip().splitlines() == [
        "python -m sumo_scendiff.train: error: --freeze-encoder needs --init-from (a trained encoder to keep)"]
