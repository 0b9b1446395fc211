"""Tests of the detection head: decoding, targets, matching, loss (sumo_scendiff/model/detection.py)."""
import math

import numpy as np
import pytest
import torch

from sumo_scendiff.core.geometry import box_corners as np_box_corners
from sumo_scendiff.core.geometry import pixel_centres
from sumo_scendiff.model.detection import (
    C_Y,
    STATIONARY,
    STRAIGHT,
    TURNING,
    DetectionLossConfig,
    accumulate_deltas,
    box_corners,
    box_targets,
    cell_centres,
    decode_boxes,
    detection_loss,
    match_boxes,
    negative_weights,
    threshold_boxes,
    trajectory_category,
    trajectory_targets,
)

CFG = DetectionLossConfig()
CENTRES = pixel_centres(100.0, (64, 64))  # (64, 64, 2)


def rot(yaw, v):
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def test_box_corners_matches_geometry():
    b = np.array([[1.0, -2.0, 0.7, 4.5, 1.8], [3.0, 4.0, -2.5, 12.0, 2.5]])
    ref = np_box_corners(*b.T)
    assert np.allclose(box_corners(torch.tensor(b)).numpy(), ref)


def test_decode_hand_constructed():
    r, c, yaw = 20, 37, 0.5
    front, left, back, right = 3.0, 1.2, 1.5, 0.6
    y = torch.zeros(2, C_Y, 64, 64)
    y[:, 0] = -10.0
    y[1, 0, r, c] = 3.0
    y[1, 1, r, c], y[1, 2, r, c] = 2 * math.cos(yaw), 2 * math.sin(yaw)  # norm does not matter
    y[1, 3:7, r, c] = torch.log(torch.tensor([front, left, back, right]))
    deltas = {-2: (-4.0, -0.1, -0.05), -1: (-4.0, 0.0, -0.05), 1: (5.0, 0.2, 0.1), 2: (6.0, 0.5, 0.2)}
    for blk, t in enumerate((-2, -1, 1, 2)):
        y[1, 7 + 3 * blk:10 + 3 * blk, r, c] = torch.tensor(deltas[t])
    dec = decode_boxes(y)
    assert dec.prob.shape == (2, 4096) and dec.boxes.shape == (2, 4096, 5) and dec.traj.shape == (2, 4096, 5, 3)

    centre = CENTRES[r, c] + rot(yaw, [(front - back) / 2, (left - right) / 2])
    k = r * 64 + c
    box = dec.boxes[1, k].double().numpy()
    assert np.allclose(box, [*centre, yaw, front + back, left + right], atol=1e-5)
    rel = {-2: (-8.0, -0.1, -0.1), -1: (-4.0, 0.0, -0.05), 1: (5.0, 0.2, 0.1), 2: (11.0, 0.7, 0.3)}
    for i, t in enumerate((-2, -1, 0, 1, 2)):
        dx, dy, dyaw = rel.get(t, (0.0, 0.0, 0.0))
        exp = [*(centre + rot(yaw, [dx, dy])), yaw + dyaw]
        assert np.allclose(dec.traj[1, k, i].double().numpy(), exp, atol=1e-4), t

    sel = threshold_boxes(dec, 0.5)
    assert len(sel[0]["prob"]) == 0 and sel[1]["cell"].tolist() == [k]


def test_targets_roundtrip():
    """box_targets + trajectory deltas at a cell inside the box decode back to the GT."""
    gt = torch.tensor([[3.1, -7.3, 2.9, 4.6, 1.9]])
    traj = torch.tensor([[[-9.0, -8.0, 2.6], [-6.0, -7.7, 2.8], [3.1, -7.3, 2.9], [0.0, -6.5, 3.1],
                          [-3.5, -5.0, -3.0]]])
    cells = cell_centres(100.0, (64, 64))
    k = int((cells - gt[0, :2]).norm(dim=-1).argmin())
    rel = trajectory_targets(gt, traj)[0]  # (5, 3)
    d = torch.stack([rel[0] - rel[1], rel[1], rel[3], rel[4] - rel[3]])  # deltas t=-2,-1,+1,+2
    d[:, 2] = torch.remainder(d[:, 2] + math.pi, 2 * math.pi) - math.pi
    assert torch.allclose(accumulate_deltas(d.reshape(12))[:, :2], rel[:, :2], atol=1e-5)
    y = torch.zeros(1, C_Y, 64, 64).flatten(2)
    y[0, 1:7, k] = box_targets(gt[0], cells[k], 0.1)
    y[0, 7:, k] = d.reshape(12)
    dec = decode_boxes(y.reshape(1, C_Y, 64, 64))
    assert torch.allclose(dec.boxes[0, k], gt[0], atol=1e-4)
    err = dec.traj[0, k] - traj[0]
    err[:, 2] = torch.remainder(err[:, 2] + math.pi, 2 * math.pi) - math.pi
    assert err.abs().max() < 1e-4


def test_box_targets_outside_cell_is_projected():
    """A cell centre outside a thin box gets finite targets describing the same-size box."""
    gt = torch.tensor([0.3, 0.3, 0.0, 2.2, 0.4])  # motorcycle-like
    cell = torch.tensor([0.3, 1.3])  # 1 m to the left of the centre, outside
    t = box_targets(gt, cell, 0.1)
    f, l, b, r = t[2:].exp()
    assert torch.isfinite(t).all()
    assert torch.allclose(f + b, gt[3]) and torch.allclose(l + r, gt[4])
    assert torch.allclose(l, torch.tensor(0.1))


def _good_y(boxes, cells_k, noise=0.3, seed=0):
    """y with noisy low-probability proposals everywhere, exact proposals at cells_k for boxes."""
    g = torch.Generator().manual_seed(seed)
    y = (noise * torch.randn(1, C_Y, 4096, generator=g))
    y[:, 0] = -6.0
    y[:, 3:7] += 0.4
    cells = cell_centres(100.0, (64, 64))
    for box, k in zip(boxes, cells_k):
        y[0, 0, k] = 4.0
        y[0, 1:7, k] = box_targets(box, cells[k], 0.1)
    return y.reshape(1, C_Y, 64, 64)


def test_match_picks_the_right_cell():
    gt = torch.tensor([[[12.0, -3.0, 0.4, 4.5, 1.9]]])
    cells = cell_centres(100.0, (64, 64))
    near = torch.argsort((cells - gt[0, 0, :2]).norm(dim=-1))[:6]
    k = int(near[3])  # not the nearest cell, but one inside the radius
    y = _good_y(gt[0], [k])
    b, n, c = match_boxes(y, gt, torch.ones(1, 1, dtype=torch.bool), CFG)
    assert b.tolist() == [0] and n.tolist() == [0] and c.tolist() == [k]


def test_match_is_one_to_one_on_collision():
    gt = torch.tensor([[[12.0, -3.0, 0.4, 4.5, 1.9], [12.3, -3.1, 0.4, 4.5, 1.9]]])
    cells = cell_centres(100.0, (64, 64))
    k = int((cells - gt[0, 0, :2]).norm(dim=-1).argmin())
    y = _good_y(gt[0, :1], [k])  # one excellent cell, best for both GTs
    valid = torch.ones(1, 2, dtype=torch.bool)
    for j in range(2):  # precondition: each GT alone picks cell k
        _, _, c = match_boxes(y, gt[:, j:j + 1], valid[:, :1], CFG)
        assert c.tolist() == [k]
    b, n, c = match_boxes(y, gt, valid, CFG)
    assert sorted(n.tolist()) == [0, 1] and len(set(c.tolist())) == 2
    assert c[n == 0].item() == k  # the exact GT keeps the cell (minimum total cost)


def test_loss_with_no_boxes_is_finite():
    y = torch.randn(3, C_Y, 64, 64, requires_grad=True)
    for n in (0, 2):
        boxes, traj = torch.zeros(3, n, 5), torch.zeros(3, n, 5, 3)
        out = detection_loss(y, boxes, traj, torch.zeros(3, n, 5, dtype=torch.bool),
                             torch.zeros(3, n, dtype=torch.bool), CFG)
        assert all(torch.isfinite(v) for v in out.values())
        assert out["matched"] == 0 and out["cls_pos"] == 0
        out["rec"].backward()
        assert torch.isfinite(y.grad).all()


def test_negative_weights_by_distance():
    gt = torch.tensor([[[0.0, 0.0, 0.0, 4.0, 2.0]]])
    valid = torch.ones(1, 1, dtype=torch.bool)
    cells = cell_centres(100.0, (64, 64))
    w = negative_weights(gt, valid, cells, CFG)[0]
    u, v = cells[:, 0].abs(), cells[:, 1].abs()
    d = torch.stack([(u - 2.0).clamp_min(0), (v - 1.0).clamp_min(0)], -1).norm(dim=-1)
    assert torch.all(w[d <= 2.9] == 0.2) and torch.all(w[d > 3.1] == CFG.neg_far_weight)
    assert (w == 0.2).sum() > 10
    assert torch.all(negative_weights(gt, ~valid, cells, CFG) == CFG.neg_far_weight)
    # in the loss: logits 0 -> cls_neg = ln 2 * (sum of weights - weight of the matched cell)
    y = torch.zeros(1, C_Y, 64, 64)
    y[:, 1] = 1.0
    traj = gt[:, :, None, :3].expand(1, 1, 5, 3)
    out = detection_loss(y, gt, traj, torch.ones(1, 1, 5, dtype=torch.bool), valid, CFG)
    assert torch.isclose(out["cls_neg"], math.log(2) * (w.sum() - 0.2), rtol=1e-4)


def test_trajectory_categories():
    boxes = torch.zeros(3, 5)
    boxes[:, 3:] = torch.tensor([4.5, 1.8])
    traj = torch.zeros(3, 5, 3)
    traj[0, :, 0] = torch.tensor([-0.2, -0.1, 0.0, 0.1, 0.2])  # creeping: stationary
    traj[0, :, 2] = torch.tensor([0.5, 0.2, 0.0, -0.2, -0.5])  # yaw noise ignored when stationary
    traj[1, :, 0] = torch.tensor([-20.0, -10.0, 0.0, 10.0, 20.0])  # straight
    traj[1, :, 2] = torch.tensor([0.05, 0.02, 0.0, -0.02, -0.05])
    traj[2, :, 0] = torch.tensor([-16.0, -8.0, 0.0, 7.0, 12.0])  # turning left, +2 s unobserved
    traj[2, :, 2] = torch.tensor([-0.2, -0.1, 0.0, 0.3, 9.9])
    mask = torch.ones(3, 5, dtype=torch.bool)
    mask[2, 4] = False
    cat = trajectory_category(trajectory_targets(boxes, traj), mask, CFG)
    assert cat.tolist() == [STATIONARY, STRAIGHT, TURNING]


def test_junction_weight_scales_the_positive_terms_of_boxes_on_a_junction():
    """junction_weight multiplies cls_pos, box, vertex and the trajectory terms of a GT box whose
    centre lies on the map's junction channel, and leaves the negatives and other boxes alone."""
    from dataclasses import replace

    from sumo_scendiff.model.detection import junction_weights
    y = torch.randn(2, C_Y, 64, 64, generator=torch.Generator().manual_seed(0))
    boxes = torch.tensor([[[10.0, -5.0, 0.3, 4.5, 1.8]], [[-20.0, 15.0, -1.0, 4.5, 1.8]]])
    traj = boxes[:, :, None, :3].expand(2, 1, 5, 3).clone()
    traj[..., 0] += torch.arange(-2.0, 3.0) * 5.0
    mask = torch.ones(2, 1, 5, dtype=torch.bool)
    valid = torch.ones(2, 1, dtype=torch.bool)
    junction = torch.zeros(2, 128, 128)
    junction[0, 64 + 4: 64 + 10, 64 + 10: 64 + 16] = 1.0  # around (10, -5) m: column right, row down
    w4 = replace(CFG, junction_weight=4.0)
    assert junction_weights(boxes[:, 0], torch.arange(2), junction, w4).tolist() == [4.0, 1.0]
    base = [detection_loss(y[i:i + 1], boxes[i:i + 1], traj[i:i + 1], mask[i:i + 1], valid[i:i + 1], CFG)
            for i in range(2)]
    both = detection_loss(y, boxes, traj, mask, valid, w4, junction=junction)
    for k in ("cls_pos", "box", "vertex", "traj_pos", "traj_yaw"):
        assert torch.allclose(both[k], (4.0 * base[0][k] + base[1][k]) / 2, rtol=1e-5), k
    assert torch.allclose(both["cls_neg"], (base[0]["cls_neg"] + base[1]["cls_neg"]) / 2, rtol=1e-5)


def test_heading_bins_round_trip_across_the_wrap_and_bin_edges():
    """heading_targets -> an ideal head decodes every heading back, on bin edges and at +-pi too;
    the residuals trained are those of the ground-truth bin and its two neighbours."""
    from sumo_scendiff.model.heading import (
        bin_width,
        decode_heading,
        heading_loss,
        heading_targets,
    )
    k = 16
    w = bin_width(k)
    yaw = torch.tensor([0.0, 0.1, 0.5 * w - 1e-4, 0.5 * w + 1e-4, -3.1, math.pi, -math.pi + 1e-3, 1.0])
    gt, res, mask = heading_targets(yaw, k)
    assert gt.tolist()[:4] == [0, 0, 0, 1] and gt[4] == gt[5] == k // 2
    assert mask.sum(1).tolist() == [3] * len(yaw) and bool(mask[torch.arange(len(yaw)), gt].all())
    assert bool((res.abs()[mask] <= 1.5 * w + 1e-5).all())
    pred = torch.zeros(len(yaw), 2 * k)
    pred[torch.arange(len(yaw)), gt] = 10.0
    pred[:, k:] = res
    err = torch.remainder(decode_heading(pred) - yaw + math.pi, 2 * math.pi) - math.pi
    assert err.abs().max() < 1e-5
    ce, l1 = heading_loss(pred, yaw)
    assert ce.max() < 1e-3 and l1.max() < 1e-6


def test_heading_head_commits_to_one_of_two_lanes():
    """Trained on a cell whose car is on either of two lanes 45 degrees apart (60 / 40), the head
    decodes the more frequent lane's heading, not a heading between the two."""
    from sumo_scendiff.model.heading import decode_heading, heading_loss
    k, lanes = 16, torch.tensor([0.3, 0.3 + math.pi / 4])
    yaw = lanes[torch.tensor([0] * 6 + [1] * 4)]
    pred = torch.zeros(1, 2 * k, requires_grad=True)
    opt = torch.optim.Adam([pred], lr=0.05)
    for _ in range(400):
        opt.zero_grad()
        ce, l1 = heading_loss(pred.expand(len(yaw), -1), yaw)
        (ce + l1).mean().backward()
        opt.step()
    assert abs(float(decode_heading(pred.detach())[0]) - 0.3) < 0.02


def test_decode_and_loss_with_a_heading_head():
    """With 2K more channels the decoded box takes the head's heading (cos/sin are ignored), its
    centre follows that heading, and the loss gains the two head terms, with gradients on the head."""
    from sumo_scendiff.model.heading import heading_targets
    k = 8
    gt = torch.tensor([[3.1, -7.3, 2.9, 4.6, 1.9]])
    cells = cell_centres(100.0, (64, 64))
    c = int((cells - gt[0, :2]).norm(dim=-1).argmin())
    y = torch.zeros(1, C_Y + 2 * k, 64 * 64)
    y[0, 0] = -10.0
    y[0, 0, c] = 10.0
    y[0, 1:7, c] = box_targets(gt[0], cells[c], 0.1)
    y[0, 1:3, c] = torch.tensor([1.0, 0.0])  # a wrong cos/sin heading: the head's wins
    b, res, _ = heading_targets(gt[0, 2:3], k)
    y[0, C_Y + int(b[0]), c] = 5.0
    y[0, C_Y + k:, c] = res[0]
    y = y.reshape(1, C_Y + 2 * k, 64, 64)
    dec = decode_boxes(y)
    assert torch.allclose(dec.boxes[0, c], gt[0], atol=1e-4)
    y.requires_grad_(True)
    traj = gt[:, None, :3].expand(1, 5, 3)[None].clone()
    out = detection_loss(y, gt[None], traj, torch.ones(1, 1, 5, dtype=torch.bool),
                         torch.ones(1, 1, dtype=torch.bool), CFG)
    assert {"heading_bin", "heading_res"} <= set(out) and float(out["heading_res"].detach()) < 1e-5
    out["rec"].backward()
    assert y.grad[0, C_Y:C_Y + k].abs().sum() > 0
    plain = detection_loss(y[:, :C_Y], gt[None], traj, torch.ones(1, 1, 5, dtype=torch.bool),
                           torch.ones(1, 1, dtype=torch.bool), CFG)
    assert "heading_bin" not in plain


def test_speed_term_is_the_l1_of_decoded_step_lengths():
    """speed_weight adds the mean L1 between decoded and GT 1 s step lengths of a matched box: 0 for
    the exact trajectory; a car that drives 5 m/s and is decoded at 7 m/s after t = 0 is off by
    (0 + 0 + 2 + 2) / 4 m/s. Off at weight 0 (the paper's loss has no such term; the shipped
    model's default weighs it)."""
    from dataclasses import replace
    yaw, v = 0.7, 5.0
    gt = torch.tensor([[3.1, -7.3, yaw, 4.6, 1.9]])
    times = torch.arange(-2.0, 3.0)[:, None]
    traj = torch.cat([gt[0, :2] + v * times * torch.tensor([math.cos(yaw), math.sin(yaw)]),
                      torch.full((5, 1), yaw)], 1)[None]
    cells = cell_centres(100.0, (64, 64))
    k = int((cells - gt[0, :2]).norm(dim=-1).argmin())
    rel = trajectory_targets(gt, traj)[0]
    d = torch.stack([rel[0] - rel[1], rel[1], rel[3], rel[4] - rel[3]])  # deltas t=-2,-1,+1,+2
    y = torch.zeros(1, C_Y, 64, 64).flatten(2)
    y[0, 0, k] = 10.0
    y[0, 1:7, k] = box_targets(gt[0], cells[k], 0.1)
    y[0, 7:, k] = d.reshape(12)
    args = (gt[None], traj[None], torch.ones(1, 1, 5, dtype=torch.bool), torch.ones(1, 1, dtype=torch.bool))
    assert "speed" not in detection_loss(y.reshape(1, C_Y, 64, 64), *args, replace(CFG, speed_weight=0.0))
    cfg = replace(CFG, speed_weight=0.5)
    assert float(detection_loss(y.reshape(1, C_Y, 64, 64), *args, cfg)["speed"]) < 1e-4
    fast = y.clone()
    fast[0, 7 + 6:7 + 12, k] *= 7.0 / 5.0          # the +1 and +2 s deltas: 7 m per step
    fast = fast.reshape(1, C_Y, 64, 64).requires_grad_(True)
    out = detection_loss(fast, *args, cfg)
    assert float(out["speed"].detach()) == pytest.approx(0.5 * (0 + 0 + 2 + 2) / 4, abs=1e-4)
    out["speed"].backward()
    assert fast.grad[0, 7 + 6:7 + 12].abs().sum() > 0
    # a box whose token gives its speed weighs 1 + told_speed_weight; the others as before
    told = replace(cfg, told_speed_weight=3.0)
    for flag, factor in ((True, 4.0), (False, 1.0)):
        got = detection_loss(fast.detach(), *args, told, told=torch.tensor([[flag]]))["speed"]
        assert float(got) == pytest.approx(factor * 0.5 * (0 + 0 + 2 + 2) / 4, abs=1e-4)
