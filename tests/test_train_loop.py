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
