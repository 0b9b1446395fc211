"""Detection head decoding and the one-to-one detection loss of the scenario autoencoder.

Paper: section 3.1 "Detection Outputs" / "Reconstruction Loss" and appendix C.2.

Output layout of ``y`` (B, C_y = 19, H'', W''), one box proposal per cell:

* 0      box logit;
* 1, 2   cos, sin of the box heading (scene frame);
* 3..6   log distances from the cell centre to the front, left, back, right box edges;
* 7..18  for the steps t = -2, -1, +1, +2 (in this order) three channels (dx, dy, dyaw).
  Future deltas are pose(t) - pose(t-1), past deltas pose(t) - pose(t+1); they are accumulated
  outward from the t = 0 box pose. (dx, dy) are expressed in the frame of the *t = 0 box*
  (x forward, y left), so the output is rotation-equivariant; dyaw is in radians.
* 19..   optionally (beyond the paper) 2K channels of a MultiBin heading head (``heading.py``):
  the decoded heading is then the head's, and cos/sin (1, 2) remain an auxiliary regression that
  the matching and the box and vertex losses use.

Conventions: cells are the pixels of ``geometry.pixel_centres(size, (H'', W''))`` flattened
row-major (index = row * W'' + col); boxes are (x, y, yaw, length, width) in scene metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..core.geometry import T0, metres_to_pixels, pixel_centres
from .heading import decode_heading, heading_loss

C_Y = 1 + 6 + 6 * 2  # channels of y for T = 2 (paper: 1 + 6 + 6T)
STEPS = (0, 1, 3, 4)  # indices into TIMES of the trajectory delta blocks (t = -2, -1, +1, +2)
STATIONARY, STRAIGHT, TURNING = 0, 1, 2  # trajectory categories (appendix C.2)


@dataclass(frozen=True)
class DetectionLossConfig:
    """Weights and thresholds of the reconstruction loss (appendix C.2); the defaults are the shipped
    decoder's (docs/model.md: why each departs from the paper's)."""

    match_cls_weight: float = 4.0  # classification weight in the matching cost
    cls_weight: float = 20.0  # classification weight in the loss on matched pairs
    box_weight: float = 4.0  # L1 on the 6 box parameters (paper: 1)
    vertex_weight: float = 2.0  # L2 (Euclidean) on the 4 box vertices (paper: 1)
    traj_pos_weight: float = 1.0  # L2 (Euclidean) on trajectory positions
    traj_yaw_weight: float = 1.0  # 1 - cos on trajectory headings
    # stationary / straight / turning (paper: 0.1 / 0.3 / 4): a turn weighted 4 is a sliver of the
    # loss, and a decoder so trained drew about half of each turn its latent and token said
    category_weights: tuple[float, float, float] = (0.1, 0.3, 40.0)
    junction_weight: float = 1.0  # every positive term of a GT box whose centre is on a junction
    stationary_threshold: float = 1.0  # m: max |p_t - p_0| over observed steps below -> stationary
    turn_threshold: float = 0.3  # rad: range of observed yaw(t) - yaw(0) above -> turning
    neg_near_weight: float = 0.2  # unmatched cells within neg_near_distance of a GT box
    neg_far_weight: float = 0.05  # all other unmatched cells (paper: 0.002; see docs/model.md)
    heading_bin_weight: float = 2.0  # cross-entropy of the MultiBin heading head (if the decoder has one)
    heading_res_weight: float = 1.0  # L1 (radians) on its residuals
    speed_weight: float = 2.0  # L1 (m/s) on the 1 s step lengths |p(t) - p(t-1)| (0: off, the paper)
    # ... of a vehicle whose token gives a speed (``told``): 1 + this many times (a decoder that reads
    # tokens; the scene's other vehicles, whose speed only the map and latent suggest, dominate it else)
    told_speed_weight: float = 10.0
    neg_near_distance: float = 3.0  # m, cell centre to the GT box outline (0 inside)
    match_radius: float = 4.0  # m, candidate cells for a GT box lie within this of its centre
    min_edge_distance: float = 0.1  # m, GT edge distances are at least this (see box_targets)
    size: float = 100.0  # m, side of the window covered by y


def wrap_angle(a: torch.Tensor) -> torch.Tensor:
    """Torch version of ``geometry.wrap_angle``: wrap to (-pi, pi] (differentiable)."""
    w = torch.remainder(a + math.pi, 2.0 * math.pi) - math.pi
    return torch.where(w <= -math.pi, w + 2.0 * math.pi, w)


def box_corners(boxes: torch.Tensor) -> torch.Tensor:
    """Torch version of ``geometry.box_corners``: (..., 5) boxes -> (..., 4, 2) corners
    in the order front-left, rear-left, rear-right, front-right."""
    x, y, yaw, length, width = boxes.unbind(-1)
    c, s = torch.cos(yaw), torch.sin(yaw)
    sl = boxes.new_tensor([1.0, -1.0, -1.0, 1.0])
    sw = boxes.new_tensor([1.0, 1.0, -1.0, -1.0])
    lx = sl * (0.5 * length)[..., None]
    ly = sw * (0.5 * width)[..., None]
    cx = x[..., None] + c[..., None] * lx - s[..., None] * ly
    cy = y[..., None] + s[..., None] * lx + c[..., None] * ly
    return torch.stack([cx, cy], dim=-1)


def cell_centres(size: float, shape: tuple[int, int], device=None) -> torch.Tensor:
    """(H*W, 2) scene-metre centres of the output cells, row-major (from ``geometry.pixel_centres``)."""
    return torch.as_tensor(pixel_centres(size, shape).reshape(-1, 2), dtype=torch.float32, device=device)


def rotate(v: torch.Tensor, c: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Rotate 2-vectors v (..., 2) by the angle with cosine c and sine s (broadcast over ...)."""
    return torch.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], dim=-1)


def params_to_boxes(p: torch.Tensor, cell_xy: torch.Tensor) -> torch.Tensor:
    """Box channels 1..6 of y, ``p`` (..., 6), at cells ``cell_xy`` (..., 2) -> boxes (..., 5).

    centre = cell + ((front - back) / 2, (left - right) / 2) in the heading frame,
    length = front + back, width = left + right, yaw = atan2(sin, cos).
    """
    cs = p[..., 0:2]
    norm = cs.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    c, s = (cs / norm).unbind(-1)
    front, left, back, right = p[..., 2:6].clamp(-7.0, 6.0).exp().unbind(-1)
    off = torch.stack([0.5 * (front - back), 0.5 * (left - right)], dim=-1)
    centre = cell_xy + rotate(off, c, s)
    yaw = torch.atan2(s, c)
    return torch.cat([centre, yaw[..., None], (front + back)[..., None], (left + right)[..., None]], -1)


def accumulate_deltas(d: torch.Tensor) -> torch.Tensor:
    """Trajectory channels (..., 12) -> poses relative to t = 0, (..., 5, 3), in the t=0 box frame.

    Section 3.1: future deltas are summed forward from t = 0, past deltas backward.
    """
    d = d.unflatten(-1, (4, 3))  # steps t = -2, -1, +1, +2
    zero = torch.zeros_like(d[..., 0, :])
    past = torch.stack([d[..., 1, :] + d[..., 0, :], d[..., 1, :]], dim=-2)
    future = torch.stack([d[..., 2, :], d[..., 2, :] + d[..., 3, :]], dim=-2)
    return torch.cat([past, zero[..., None, :], future], dim=-2)


@dataclass
class DecodedBoxes:
    """Dense decoded proposals, K = H'' * W'' per scene (all in scene frame)."""

    prob: torch.Tensor  # (B, K) box probability
    boxes: torch.Tensor  # (B, K, 5) x, y, yaw, length, width at t = 0
    traj: torch.Tensor  # (B, K, 5, 3) x, y, yaw at t = -2, -1, 0, +1, +2


def decode_boxes(y: torch.Tensor, size: float = 100.0, yaw: torch.Tensor | None = None) -> DecodedBoxes:
    """Decode every cell of ``y`` (B, 19 [+ 2K], H, W) into a box with a trajectory (section 3.1).
    With a heading head (channels 19..), the box heading is the head's argmax bin plus residual;
    ``yaw`` (B, H*W) gives the headings instead (``lane_heading.junction_yaw``)."""
    b, _, h, w = y.shape
    yf = y.flatten(2).transpose(1, 2)  # (B, K, 19 [+ 2K])
    cells = cell_centres(size, (h, w), y.device)
    params = yf[..., 1:7]
    if yaw is None and y.shape[1] > C_Y:
        yaw = decode_heading(yf[..., C_Y:])
    if yaw is not None:
        params = torch.cat([torch.cos(yaw)[..., None], torch.sin(yaw)[..., None], params[..., 2:]], -1)
    boxes = params_to_boxes(params, cells)
    rel = accumulate_deltas(yf[..., 7:C_Y])  # (B, K, 5, 3) in the box frame
    c, s = torch.cos(boxes[..., 2:3]), torch.sin(boxes[..., 2:3])
    xy = boxes[..., None, 0:2] + rotate(rel[..., 0:2], c, s)
    yaw = wrap_angle(boxes[..., None, 2] + rel[..., 2])
    return DecodedBoxes(torch.sigmoid(yf[..., 0]), boxes, torch.cat([xy, yaw[..., None]], -1))


def threshold_boxes(dec: DecodedBoxes, threshold: float = 0.5) -> list[dict[str, torch.Tensor]]:
    """Per scene, the proposals with probability >= threshold, most probable first.

    Returns a list of B dicts with ``prob`` (n,), ``boxes`` (n, 5), ``traj`` (n, 5, 3), ``cell`` (n,).
    Overlap removal is done downstream.
    """
    out = []
    for i in range(dec.prob.shape[0]):
        keep = torch.nonzero(dec.prob[i] >= threshold).squeeze(1)
        keep = keep[torch.argsort(dec.prob[i, keep], descending=True)]
        out.append(dict(prob=dec.prob[i, keep], boxes=dec.boxes[i, keep], traj=dec.traj[i, keep], cell=keep))
    return out


def box_targets(boxes: torch.Tensor, cell_xy: torch.Tensor, eps: float) -> torch.Tensor:
    """GT box channels (cos, sin, log front, log left, log back, log right) for boxes (..., 5) at
    cells (..., 2).

    Log distances need positive distances, i.e. the cell centre inside the box. A cell centre
    outside (or within ``eps`` of an edge) is first projected to the nearest point of the box
    shrunk by ``eps``: the target is then the closest box this cell can express (same yaw, length,
    width; centre shifted by the projection). Small boxes may contain no cell centre at all, so
    this keeps every candidate usable; the vertex loss still compares with the true box.
    """
    c, s = torch.cos(boxes[..., 2]), torch.sin(boxes[..., 2])
    hl, hw = 0.5 * boxes[..., 3], 0.5 * boxes[..., 4]
    uv = rotate(cell_xy - boxes[..., 0:2], c, -s)  # cell in the GT box frame
    bl, bw = (hl - eps).clamp_min(0.0), (hw - eps).clamp_min(0.0)
    u = torch.maximum(torch.minimum(uv[..., 0], bl), -bl)
    v = torch.maximum(torch.minimum(uv[..., 1], bw), -bw)
    dist = torch.stack([hl - u, hw - v, hl + u, hw + v], dim=-1).clamp_min(1e-3)
    return torch.cat([c[..., None], s[..., None], dist.log()], dim=-1)


def pair_costs(pred: torch.Tensor, cell_xy: torch.Tensor, gt: torch.Tensor, eps: float) -> dict:
    """Per-pair terms for predictions (..., 19) at cells (..., 2) against GT boxes (..., 5):
    ``cls`` BCE(logit, 1), ``box`` mean L1 over the 6 box parameters, ``vertex`` mean Euclidean
    distance over the 4 corners (appendix C.2)."""
    cls = F.softplus(-pred[..., 0])
    box = (pred[..., 1:7] - box_targets(gt, cell_xy, eps)).abs().mean(-1)
    corners = box_corners(params_to_boxes(pred[..., 1:7], cell_xy))
    vertex = (corners - box_corners(gt)).norm(dim=-1).mean(-1)
    return dict(cls=cls, box=box, vertex=vertex)


def trajectory_targets(boxes: torch.Tensor, traj: torch.Tensor) -> torch.Tensor:
    """GT poses relative to the t = 0 box, in the t = 0 box frame: (..., 5, 3)."""
    c, s = torch.cos(boxes[..., None, 2]), torch.sin(boxes[..., None, 2])
    xy = rotate(traj[..., 0:2] - boxes[..., None, 0:2], c, -s)
    return torch.cat([xy, wrap_angle(traj[..., 2] - boxes[..., None, 2])[..., None]], -1)


def trajectory_category(rel: torch.Tensor, mask: torch.Tensor, cfg: DetectionLossConfig) -> torch.Tensor:
    """Stationary / straight / turning (appendix C.2) from GT relative poses (..., 5, 3), mask (..., 5).

    stationary: every observed position within ``stationary_threshold`` m of the t=0 box centre;
    turning: otherwise, if the range of observed yaw(t) - yaw(0) (t = 0 included) exceeds
    ``turn_threshold`` rad; straight: the rest. Unobserved steps are ignored.
    """
    m = mask.clone()
    m[..., T0] = True
    disp = torch.where(m, rel[..., 0:2].norm(dim=-1), torch.zeros_like(rel[..., 0]))
    yaw = rel[..., 2]
    yaw_range = (torch.where(m, yaw, yaw.new_tensor(-1e9)).amax(-1)
                 - torch.where(m, yaw, yaw.new_tensor(1e9)).amin(-1))
    cat = torch.full(yaw.shape[:-1], STRAIGHT, dtype=torch.long, device=rel.device)
    cat = torch.where(yaw_range > cfg.turn_threshold, torch.full_like(cat, TURNING), cat)
    return torch.where(disp.amax(-1) < cfg.stationary_threshold, torch.full_like(cat, STATIONARY), cat)


@torch.no_grad()
def match_boxes(y: torch.Tensor, boxes: torch.Tensor, valid: torch.Tensor,
                cfg: DetectionLossConfig) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One-to-one matching of GT boxes to predicted cells (appendix C.2, after POTO).

    Cost = match_cls_weight * BCE(logit, 1) + L1(box params) + L2(vertices). Candidates for a GT
    box are the cells within ``match_radius`` m of its centre (or, if none, the nearest cell). Each
    GT takes its cheapest candidate; if two GTs of a scene pick the same cell the scene is solved
    exactly with the Hungarian algorithm on its (GT x candidate cell) cost matrix.

    Returns (b, n, cell) long tensors, one entry per matched GT box.
    """
    bsz, _, h, w = y.shape
    n = boxes.shape[1]
    empty = torch.zeros(0, dtype=torch.long, device=y.device)
    if n == 0 or not bool(valid.any()):
        return empty, empty, empty
    k = math.ceil(cfg.match_radius / (cfg.size / w))
    colrow = np.rint(metres_to_pixels(boxes[..., 0:2].detach().cpu().numpy(), cfg.size, (h, w)))
    col0 = np.clip(colrow[..., 0], 0, w - 1).astype(np.int64)
    row0 = np.clip(colrow[..., 1], 0, h - 1).astype(np.int64)
    off = np.arange(-k, k + 1)
    rows = row0[..., None, None] + off[:, None]  # (B, N, P1, 1)
    cols = col0[..., None, None] + off[None, :]  # (B, N, 1, P1)
    inside = ((rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)).reshape(bsz, n, -1)
    idx = (np.clip(rows, 0, h - 1) * w + np.clip(cols, 0, w - 1)).reshape(bsz, n, -1)
    idx = torch.as_tensor(idx, device=y.device)
    inside = torch.as_tensor(inside, device=y.device)

    cells = cell_centres(cfg.size, (h, w), y.device)[idx]  # (B, N, P, 2)
    dist = (cells - boxes[..., None, 0:2]).norm(dim=-1)
    dmin = torch.where(inside, dist, torch.full_like(dist, 1e9)).amin(-1, keepdim=True)
    cand = inside & (dist <= torch.clamp(dmin + 1e-4, min=cfg.match_radius)) & valid[..., None]

    pred = y.flatten(2).transpose(1, 2)  # (B, K, 19)
    pred = torch.gather(pred, 1, idx.reshape(bsz, -1, 1).expand(-1, -1, y.shape[1])).reshape(*idx.shape, -1)
    t = pair_costs(pred, cells, boxes[..., None, :].expand(*idx.shape, 5), cfg.min_edge_distance)
    cost = cfg.match_cls_weight * t["cls"] + t["box"] + t["vertex"]
    cost = torch.where(cand, cost, torch.full_like(cost, float("inf")))

    best = torch.gather(idx, 2, cost.argmin(-1, keepdim=True)).squeeze(-1)  # (B, N)
    out_b, out_n, out_c = [], [], []
    for i in range(bsz):
        gts = torch.nonzero(valid[i]).squeeze(1)
        cells_i = best[i, gts]
        if len(torch.unique(cells_i)) < len(cells_i):  # collision: exact assignment for this scene
            c_np, idx_np = cost[i, gts].cpu().numpy(), idx[i, gts].cpu().numpy()
            finite = np.isfinite(c_np)
            uniq, inv = np.unique(idx_np[finite], return_inverse=True)
            mat = np.full((len(gts), len(uniq)), 1e12)
            mat[np.nonzero(finite)[0], inv] = c_np[finite]
            from scipy.optimize import linear_sum_assignment   # only here: generation without tokens never loads scipy
            r, c = linear_sum_assignment(mat)
            ok = mat[r, c] < 1e12
            gts = gts[torch.as_tensor(r[ok], device=y.device)]
            cells_i = torch.as_tensor(uniq[c[ok]], device=y.device)
        out_b.append(torch.full_like(gts, i))
        out_n.append(gts)
        out_c.append(cells_i)
    return torch.cat(out_b), torch.cat(out_n), torch.cat(out_c)


@torch.no_grad()
def negative_weights(boxes: torch.Tensor, valid: torch.Tensor, cells: torch.Tensor,
                     cfg: DetectionLossConfig) -> torch.Tensor:
    """(B, K) weights of the "probability 0" BCE for every cell (appendix C.2): ``neg_near_weight``
    if the cell centre is within ``neg_near_distance`` m of a GT box (distance to the box outline,
    0 inside), else ``neg_far_weight``. Matched cells are zeroed by the caller."""
    near = torch.zeros(boxes.shape[0], cells.shape[0], dtype=torch.bool, device=cells.device)
    for j in range(0, boxes.shape[1], 16):  # chunks of GT slots keep memory at O(16 B K)
        bx, ok = boxes[:, j:j + 16, None], valid[:, j:j + 16, None]  # (B, n, 1, 5), (B, n, 1)
        c, s = torch.cos(bx[..., 2]), torch.sin(bx[..., 2])
        uv = rotate(cells - bx[..., 0:2], c, -s).abs()  # (B, n, K, 2) in the box frame
        d = (uv - 0.5 * bx[..., 3:5]).clamp_min(0.0).norm(dim=-1)
        near |= ((d <= cfg.neg_near_distance) & ok).any(1)
    return torch.where(near, cfg.neg_near_weight, cfg.neg_far_weight).to(cells.dtype)


def on_junction(boxes: torch.Tensor, scene: torch.Tensor, junction: torch.Tensor, size: float) -> torch.Tensor:
    """(M,) bool: whether the centre pixel of each box (M, 5) is set in the junction channel of its
    scene's map raster, ``junction[scene]`` (``junction`` (B, H, W), a ``size`` m window)."""
    h, w = junction.shape[-2:]
    colrow = np.rint(metres_to_pixels(boxes[:, 0:2].detach().cpu().numpy(), size, (h, w)))
    col = torch.as_tensor(np.clip(colrow[:, 0], 0, w - 1).astype(np.int64), device=boxes.device)
    row = torch.as_tensor(np.clip(colrow[:, 1], 0, h - 1).astype(np.int64), device=boxes.device)
    return junction[scene, row, col] > 0.5


def junction_weights(boxes: torch.Tensor, scene: torch.Tensor, junction: torch.Tensor,
                     cfg: DetectionLossConfig) -> torch.Tensor:
    """(M,) ``cfg.junction_weight`` for GT boxes (M, 5) centred on a junction (:func:`on_junction`),
    1 elsewhere."""
    return torch.where(on_junction(boxes, scene, junction, cfg.size), boxes.new_tensor(cfg.junction_weight),
                       boxes.new_tensor(1.0))


def _trajectory_errors(pred: torch.Tensor, rel_gt: torch.Tensor, mask: torch.Tensor):
    """(the decoded trajectory relative to its box (M, 5, 3), the position error in metres (M,), the
    heading error 1 - cos (M,)) of matched predictions ``pred`` (M, 19 [+ 2K]) against ``rel_gt``,
    each the mean over the steps t != 0 that ``mask`` (M, 5) has observed."""
    m = mask.clone()
    m[:, T0] = False
    rel = accumulate_deltas(pred[:, 7:C_Y])
    mf = m.to(pred.dtype)
    steps = mf.sum(-1).clamp_min(1.0)
    pos = ((rel[..., 0:2] - rel_gt[..., 0:2]).norm(dim=-1) * mf).sum(-1) / steps
    yaw = ((1.0 - torch.cos(rel[..., 2] - rel_gt[..., 2])) * mf).sum(-1) / steps
    return rel, pos, yaw


def _speed_errors(rel: torch.Tensor, rel_gt: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(M,) the L1 between decoded and GT step lengths |p(t) - p(t-1)| over the 1 s steps whose
    both ends ``mask`` (M, 5) has observed (the box pose itself always), mean per box."""
    seen = mask.clone()
    seen[:, T0] = True                                  # the box pose itself
    both = (seen[:, 1:] & seen[:, :-1]).to(rel.dtype)  # (M, 4) steps with both ends observed
    v = (rel[:, 1:, 0:2] - rel[:, :-1, 0:2]).norm(dim=-1)
    v_gt = (rel_gt[:, 1:, 0:2] - rel_gt[:, :-1, 0:2]).norm(dim=-1)
    return ((v - v_gt).abs() * both).sum(-1) / both.sum(-1).clamp_min(1.0)


def detection_loss(y: torch.Tensor, boxes: torch.Tensor, traj: torch.Tensor, traj_mask: torch.Tensor,
                   valid: torch.Tensor, cfg: DetectionLossConfig,
                   junction: torch.Tensor | None = None, told: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Reconstruction loss L_rec (appendix C.2) of ``y`` (B, 19 [+ 2K], H, W) against padded GT.

    Normalisation: every term is *summed* over the matched GT boxes (resp. over all unmatched
    cells for ``cls_neg``) of a scene and averaged over the B scenes, i.e. a per-scene sum, the
    same reduction as the KL term of the autoencoder. Within a pair, the box L1 is the mean over
    its 6 parameters, the vertex loss the mean corner distance, the trajectory losses the mean
    over the observed steps t != 0 (positions: Euclidean distance in metres; headings: 1 - cos),
    multiplied by the GT trajectory's category weight. With ``junction`` (B, H, W), the map raster's
    junction channel, every positive term of a box centred on a junction is multiplied by
    ``cfg.junction_weight``. A MultiBin heading head adds ``heading_bin`` (cross-entropy) and
    ``heading_res`` (residual L1) per matched box. ``cfg.speed_weight`` > 0 adds ``speed``: the L1
    between decoded and GT step lengths |p(t) - p(t-1)| over the 1 s steps with both ends observed
    (the speeds ``generate.speeds_from_traj`` reports), mean per box, without the category weight
    that scales straight-driving boxes' positions by 0.3; ``told`` (B, N), the GT boxes whose token
    gives a speed or final speed, weighs theirs ``1 + cfg.told_speed_weight``. Works with N = 0.
    """
    bsz, _, h, w = y.shape
    cells = cell_centres(cfg.size, (h, w), y.device)
    b, n, c = match_boxes(y, boxes, valid, cfg)
    yf = y.flatten(2)  # (B, 19, K)
    pred = yf[b, :, c]  # (M, 19)
    gt = boxes[b, n]
    t = pair_costs(pred, cells[c], gt, cfg.min_edge_distance)

    rel_gt = trajectory_targets(gt, traj[b, n])  # (M, 5, 3)
    rel, pos, yaw = _trajectory_errors(pred, rel_gt, traj_mask[b, n])
    cat_w = y.new_tensor(cfg.category_weights)[trajectory_category(rel_gt, traj_mask[b, n], cfg)]
    jw = (junction_weights(gt, b, junction, cfg) if junction is not None and cfg.junction_weight != 1.0
          else y.new_ones(len(b)))

    neg_w = negative_weights(boxes, valid, cells, cfg)
    neg_w[b, c] = 0.0
    out = dict(
        cls_pos=cfg.cls_weight * (jw * t["cls"]).sum() / bsz,
        cls_neg=(neg_w * F.softplus(yf[:, 0])).sum() / bsz,
        box=cfg.box_weight * (jw * t["box"]).sum() / bsz,
        vertex=cfg.vertex_weight * (jw * t["vertex"]).sum() / bsz,
        traj_pos=cfg.traj_pos_weight * (jw * cat_w * pos).sum() / bsz,
        traj_yaw=cfg.traj_yaw_weight * (jw * cat_w * yaw).sum() / bsz,
    )
    if cfg.speed_weight > 0:
        err = _speed_errors(rel, rel_gt, traj_mask[b, n])
        if told is not None and cfg.told_speed_weight:   # the boxes whose token gives a speed
            err = err * (1.0 + cfg.told_speed_weight * told[b, n].to(y.dtype))
        out["speed"] = cfg.speed_weight * (jw * err).sum() / bsz
    if y.shape[1] > C_Y:  # MultiBin heading head
        ce, res = heading_loss(pred[:, C_Y:], gt[:, 2])
        out["heading_bin"] = cfg.heading_bin_weight * (jw * ce).sum() / bsz
        out["heading_res"] = cfg.heading_res_weight * (jw * res).sum() / bsz
    out["rec"] = sum(out.values())
    out["matched"] = torch.tensor(float(len(b)), device=y.device)  # diagnostic, not a loss
    return out
