"""The paper's evaluation metrics (sec. 4.1 "Metrics", sec. 4.3.1-4.3.2, appendix E.2) as pure functions.

Distribution metrics (generated vs ground-truth scenes of the same windows, one network):

* MMD² (biased V-statistic, Gaussian kernel) of agent centre positions, heading unit vectors and
  velocities, each in R², plus a joint MMD² over the concatenation of the three (each scaled by its
  bandwidth, sigma = 1, i.e. the product of the three marginal kernels). It is computed **per scene**
  between the generated and the ground-truth agents of that window, then averaged over the scenes
  where both sets are non-empty (a pooled MMD could not see the map). Features are taken in the
  ground-truth window's scene frame.
* agents-per-scene EMD: earth mover's distance between the two distributions of agent counts (this
  is where empty / miscounted scenes show up).
* trajectory metrics: fraction of observed waypoints on the drivable area, and the mean minimum
  angle between a waypoint's heading and the car lanes at that location.

Token matching metrics (sec. 4.3.1, app. E.2): a one-to-one Hungarian matching of generated agents to
agent tokens on centre distance, with only pairs within :data:`MATCH_DISTANCE` and
:data:`MATCH_HEADING` allowed; then match rate (= recall), additional agents per scene (= FP per
scene), precision, recall, F1, and speed MAE over matched pairs.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.distance import cdist
from scipy.stats import wasserstein_distance

from ..core.geometry import T0, T_FINAL, TIMES, Window
from ..core.matching import MATCH_DISTANCE, MATCH_HEADING, match_agents
from ..core.scene import Scene

SIGMA_POSITION = 5.0    # m: Gaussian kernel bandwidth for centre positions (about one car length + gap)
SIGMA_HEADING = 0.5     # heading unit vectors (cos, sin): 0.5 ~ 29 degrees of disagreement
SIGMA_VELOCITY = 2.0    # m/s: velocity vectors speed * (cos, sin) at t = 0
SIGMA_JOINT = 1.0       # on (position / 5, heading / 0.5, velocity / 2): the product of the marginals
LANE_RADIUS = 2.0       # m: "lanes at that location" = car lanes whose polygon is within 2 m
WINDOW_TOLERANCE = 0.01  # m: generated[i] and ground_truth[i] must share the window centre


# ---- MMD ---------------------------------------------------------------------------------------
def gaussian_kernel(a: np.ndarray, b: np.ndarray, sigma: float) -> np.ndarray:
    """k(a, b) = exp(-||a - b||² / (2 sigma²)) for all pairs: (n, d), (m, d) -> (n, m)."""
    d2 = cdist(np.asarray(a, np.float64), np.asarray(b, np.float64), "sqeuclidean")
    return np.exp(-d2 / (2.0 * sigma * sigma))


def mmd2(a: np.ndarray, b: np.ndarray, sigma: float) -> float:
    """The paper's MMD² (sec. 4.1), the biased V-statistic with a Gaussian kernel k:

        MMD²(A, B) = 1/|A|² Σ_{a1,a2∈A} k(a1,a2) + 1/|B|² Σ_{b1,b2∈B} k(b1,b2) - 2/(|A||B|) Σ_{a∈A,b∈B} k(a,b)

    ``a`` (n, d), ``b`` (m, d), both non-empty. Always >= 0 (up to rounding), 0 for identical sets.
    """
    a, b = np.atleast_2d(np.asarray(a, np.float64)), np.atleast_2d(np.asarray(b, np.float64))
    if len(a) == 0 or len(b) == 0:
        raise ValueError("mmd2 needs two non-empty sets")
    return float(gaussian_kernel(a, a, sigma).mean() + gaussian_kernel(b, b, sigma).mean()
                 - 2.0 * gaussian_kernel(a, b, sigma).mean())


def agent_features(scene: Scene, frame: Window | None = None) -> dict[str, np.ndarray]:
    """Per-agent MMD features at t = 0 in the scene frame of ``frame`` (default: the scene's window):
    ``position`` (N, 2) centres, ``heading`` (N, 2) unit vectors (cos, sin), ``velocity`` (N, 2)
    speed * (cos, sin), and ``joint`` (N, 6) = (position / 5, heading / 0.5, velocity / 2)."""
    frame = scene.window if frame is None else frame
    xy = frame.world_to_scene(scene.window.scene_to_world(scene.boxes[:, :2].astype(np.float64)))
    yaw = frame.yaw_to_scene(scene.window.yaw_to_world(scene.boxes[:, 2].astype(np.float64)))
    head = np.stack([np.cos(yaw), np.sin(yaw)], -1).reshape(-1, 2)
    vel = head * scene.speed[:, T0:T0 + 1].astype(np.float64)
    xy = xy.reshape(-1, 2)
    joint = np.concatenate([xy / SIGMA_POSITION, head / SIGMA_HEADING, vel / SIGMA_VELOCITY], -1)
    return {"position": xy, "heading": head, "velocity": vel, "joint": joint}


MMD_SIGMAS = {"position": SIGMA_POSITION, "heading": SIGMA_HEADING, "velocity": SIGMA_VELOCITY,
              "joint": SIGMA_JOINT}


def scene_mmd2(generated: Scene, ground_truth: Scene) -> dict[str, float] | None:
    """MMD² of each feature (:data:`MMD_SIGMAS`) between the agents of one generated scene and the
    ground-truth scene of the same window, in the ground-truth frame; ``None`` if either is empty."""
    if len(generated) == 0 or len(ground_truth) == 0:
        return None
    fg = agent_features(generated, ground_truth.window)
    ft = agent_features(ground_truth)
    return {k: mmd2(fg[k], ft[k], s) for k, s in MMD_SIGMAS.items()}


def mean_scene_mmd2(generated: Sequence[Scene], ground_truth: Sequence[Scene]) -> dict[str, float]:
    """Per-scene MMD² (:func:`scene_mmd2`) averaged over the scenes where both sets are non-empty:
    ``mmd2_position``, ``mmd2_heading``, ``mmd2_velocity``, ``mmd2_joint`` (NaN if no scene qualifies)
    and ``mmd_scenes``, the number of scenes used."""
    vals = [v for v in map(scene_mmd2, generated, ground_truth) if v is not None]
    out = {f"mmd2_{k}": float(np.mean([v[k] for v in vals])) if vals else float("nan")
           for k in MMD_SIGMAS}
    out["mmd_scenes"] = len(vals)
    return out


# ---- trajectory metrics ------------------------------------------------------------------------
def observed_world_poses(scenes: Sequence[Scene]) -> tuple[np.ndarray, np.ndarray]:
    """World (x, y) (P, 2) and world yaw (P,) of every observed waypoint (all 5 poses where traj_mask)
    of every agent of every scene."""
    xy, yaw = [np.zeros((0, 2))], [np.zeros(0)]
    for s in scenes:
        m = s.traj_mask
        if m.any():
            xy.append(s.window.scene_to_world(s.traj[..., :2][m].astype(np.float64)))
            yaw.append(s.window.yaw_to_world(s.traj[..., 2][m].astype(np.float64)))
    return np.concatenate(xy), np.concatenate(yaw)


def traj_on_drivable(scenes: Sequence[Scene], net) -> float:
    """Traj on drivable (sec. 4.1): fraction of observed waypoints (pooled over all agents and their
    up to 5 poses) that lie on the drivable area (a car lane or a junction); NaN without waypoints."""
    xy, _ = observed_world_poses(scenes)
    return float(net.on_drivable(xy).mean()) if len(xy) else float("nan")


def lane_heading_difference(scenes: Sequence[Scene], net, radius: float = LANE_RADIUS
                            ) -> tuple[float, float]:
    """Lane heading difference (sec. 4.1): mean over observed waypoints of the minimum angle (rad,
    in [0, pi]) between the pose heading and the headings of all car lanes at that location (within
    ``radius`` m). Waypoints with no car lane there are excluded. Returns ``(mean, excluded
    fraction)``; the mean is NaN when every waypoint is excluded."""
    xy, yaw = observed_world_poses(scenes)
    if len(xy) == 0:
        return float("nan"), float("nan")
    diff = net.lane_heading_difference(xy, yaw, radius=radius)
    ok = np.isfinite(diff)
    return (float(diff[ok].mean()) if ok.any() else float("nan")), float(1.0 - ok.mean())


def agents_per_scene_emd(counts_a: Sequence[int], counts_b: Sequence[int]) -> float:
    """Earth mover's (1-Wasserstein) distance between two empirical distributions of agents per
    scene: the mean number of agents that must be added/removed per scene to turn one into the other."""
    return float(wasserstein_distance(np.asarray(counts_a, np.float64), np.asarray(counts_b, np.float64)))


def trajectory_metrics(scenes: Sequence[Scene], net) -> dict[str, float]:
    """``traj_on_drivable``, ``lane_heading_diff`` and ``lane_heading_excluded`` of a set of scenes."""
    lhd, excl = lane_heading_difference(scenes, net)
    return {"traj_on_drivable": traj_on_drivable(scenes, net), "lane_heading_diff": lhd,
            "lane_heading_excluded": excl}


STANDING_SPEED = 0.5    # m/s: a vehicle slower than this stands
QUEUE_REACH = 50.0      # m before the stop line: a vehicle this close is queued at its light (or passes it)


def signal_standing(scenes: Sequence[Scene], net, signals: Sequence[dict | None]) -> dict[str, float]:
    """The share of vehicles standing (below :data:`STANDING_SPEED`) among those within
    :data:`QUEUE_REACH` m of the stop line of a lane whose light is red, and among those whose light
    is green; ``signals[i]`` is the light states (tls id -> state string) at scene ``i``'s time.
    Returns ``standing_red``, ``standing_green`` (nan without such vehicles) and their counts."""
    from ..map.signals import lane_lights
    counts = {"red": [0, 0], "green": [0, 0]}
    for scene, states in zip(scenes, signals):
        if not states or not len(scene):
            continue
        lights = lane_lights(net, states)
        agents = scene.world_agents()
        m = net.match_poses([[a["x"], a["y"]] for a in agents], [a["heading"] for a in agents])
        for i, lane in enumerate(m.lane):
            kind = lights.get(int(lane))
            if kind is not None and net.lanes[int(lane)].length - m.pos[i] <= QUEUE_REACH:
                counts[kind][0] += 1
                counts[kind][1] += float(scene.speed[i, T0]) < STANDING_SPEED
    out = {}
    for kind, (n, standing) in counts.items():
        out[f"standing_{kind}"] = standing / n if n else float("nan")
        out[f"at_{kind}"] = n
    return out


def check_pairing(generated: Sequence[Scene], ground_truth: Sequence[Scene]) -> None:
    """Raise ValueError unless ``generated[i]`` is for the window of ``ground_truth[i]``."""
    if len(generated) != len(ground_truth):
        raise ValueError(f"{len(generated)} generated scenes for {len(ground_truth)} ground-truth scenes")
    for i, (g, t) in enumerate(zip(generated, ground_truth)):
        if np.hypot(g.window.cx - t.window.cx, g.window.cy - t.window.cy) > WINDOW_TOLERANCE:
            raise ValueError(f"generated[{i}] is for window {g.window}, ground_truth[{i}] for {t.window}")


def evaluate_scenes(generated: Sequence[Scene], ground_truth: Sequence[Scene], net) -> dict:
    """All distribution metrics of sec. 4.1 for one network; ``generated[i]`` is for the window of
    ``ground_truth[i]`` (same centre; the yaw may differ, features are taken in the ground-truth frame).

    Returns: ``scenes``; the :func:`mean_scene_mmd2` entries (``mmd2_*``, ``mmd_scenes``);
    ``agents_per_scene_emd``, ``agents_per_scene_gen``/``_gt`` (means); the generated scenes'
    :func:`trajectory_metrics`; with the recorded lights, :func:`signal_standing` (each generated
    scene judged under its ground truth's lights); and ``gt_only``: the trajectory metrics (and signal
    standing) of the ground truth itself.
    """
    check_pairing(generated, ground_truth)
    n_gen = [len(s) for s in generated]
    n_gt = [len(s) for s in ground_truth]
    out: dict = {"scenes": len(ground_truth)}
    out.update(mean_scene_mmd2(generated, ground_truth))
    out["agents_per_scene_emd"] = agents_per_scene_emd(n_gen, n_gt) if n_gt else float("nan")
    out["agents_per_scene_gen"] = float(np.mean(n_gen)) if n_gen else float("nan")
    out["agents_per_scene_gt"] = float(np.mean(n_gt)) if n_gt else float("nan")
    out.update(trajectory_metrics(generated, net))
    out["gt_only"] = trajectory_metrics(ground_truth, net)
    lights = [t.meta.get("signals") or None for t in ground_truth]   # the recorded moment's lights
    if any(lights):
        out.update(signal_standing(generated, net, lights))
        out["gt_only"].update(signal_standing(ground_truth, net, lights))
    return out


# ---- token matching ----------------------------------------------------------------------------
def precision_recall_f1(tp: int, fp: int, fn: int) -> dict[str, float]:
    """App. E.2: precision = TP/(TP+FP), recall = TP/(TP+FN) (= agent token match rate),
    F1 = 2 P R / (P + R), computed as 2 TP / (2 TP + FP + FN) (equal where both are defined; 0 when
    TP = 0). NaN where a denominator is 0."""
    nan = float("nan")
    return {"precision": tp / (tp + fp) if tp + fp else nan,
            "recall": tp / (tp + fn) if tp + fn else nan,
            "f1": 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else nan}


def speed_errors(gen: Scene, tok: Scene, gi: np.ndarray, ti: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Absolute speed errors of matched pairs: current (t = 0, every pair) and final (t = +2 s, only
    pairs where that pose is observed in both)."""
    cur = np.abs(gen.speed[gi, T0].astype(np.float64) - tok.speed[ti, T0])
    both = gen.traj_mask[gi, T_FINAL] & tok.traj_mask[ti, T_FINAL]
    fin = np.abs(gen.speed[gi[both], T_FINAL].astype(np.float64) - tok.speed[ti[both], T_FINAL])
    return cur, fin


def token_metrics(generated: Sequence[Scene], tokens: Sequence[Scene],
                  max_distance: float = MATCH_DISTANCE, max_heading: float = MATCH_HEADING) -> dict:
    """Token matching metrics (sec. 4.3.1, 4.3.2, app. E.2) aggregated over scenes.

    ``tokens[i]`` holds the ground-truth agents the agent tokens of scene i were computed from (e.g.
    ``gt.select(kept)`` after token masking); ``generated[i]`` the scene generated from them. Tokens
    are taken in the generated window's frame. Per scene, :func:`match_agents`; pooled over scenes:
    TP = matched pairs, FN = unmatched tokens, FP = unmatched generated agents.

    Returns ``match_rate`` (= recall = TP / tokens), ``additional_per_scene`` (FP / scenes),
    ``precision``, ``recall``, ``f1``, ``speed_mae`` (current speed, all matched pairs),
    ``final_speed_mae`` (t = +2 s, pairs observed at +2 s in both), and the counts ``tp``, ``fp``,
    ``fn``, ``scenes``, ``final_speed_pairs``.
    """
    check_pairing(generated, tokens)
    tp = fp = fn = 0
    cur, fin = [np.zeros(0)], [np.zeros(0)]
    for gen, tok in zip(generated, tokens):
        tb = tok.boxes[:, :3].astype(np.float64)
        tb[:, :2] = gen.window.world_to_scene(tok.window.scene_to_world(tb[:, :2]))
        tb[:, 2] = gen.window.yaw_to_scene(tok.window.yaw_to_world(tb[:, 2]))
        gi, ti = match_agents(gen.boxes[:, :3], tb, max_distance, max_heading)
        tp, fp, fn = tp + len(gi), fp + len(gen) - len(gi), fn + len(tok) - len(ti)
        c, f = speed_errors(gen, tok, gi, ti)
        cur.append(c)
        fin.append(f)
    cur_a, fin_a = np.concatenate(cur), np.concatenate(fin)
    out = precision_recall_f1(tp, fp, fn)
    out.update({"match_rate": out["recall"],
                "additional_per_scene": fp / len(generated) if len(generated) else float("nan"),
                "speed_mae": float(cur_a.mean()) if len(cur_a) else float("nan"),
                "final_speed_mae": float(fin_a.mean()) if len(fin_a) else float("nan"),
                "tp": tp, "fp": fp, "fn": fn, "scenes": len(generated), "final_speed_pairs": len(fin_a)})
    return out
