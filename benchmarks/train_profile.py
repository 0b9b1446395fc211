"""Benchmark: where a training step's CPU time goes, stage by stage, and where a recording's goes.

    python benchmarks/train_profile.py --data DIR [--steps 6] [--warmup 2] [--results results/train_profile.json] [-o table.md]
        [--model-config '{"stem": "stride2"}']
    python -m sumo_scendiff.data -n networks/grid4x4_2lane_tls.net.xml -o DIR --scenes 200 -s 0   # a small DIR

Training: each training stage of ``configs/scendiff.json`` (autoencoder, decoder, diffusion) runs
in a Python process of its own with one thread, built by the stage's real code from the recipe's
own command line (``train recipe``'s stage arguments: model config, settings, optimiser, batch per
DDP process) reading ``--data``; only the loop's ``run`` is replaced by one that times ``--warmup``
+ ``--steps`` steps and keeps the last ``--steps``. The decoder stage starts from the autoencoder
run's checkpoint and the diffusion stage's latent space is it (its latent scale is not estimated:
1; speed does not depend on it). CPU seconds per step (``time.process_time``) are split into
exclusive phases that add up to the whole: data loading (reading the scene, turning it, the
density's lane length, map raster, agent raster, collation, the loader's own), token preparation,
every block of the model's forward (forward hooks; the blocks' glue is the model's own row), the
loss, the backward (each block's backward from its output's gradient to its last weight's
gradient; the rest of autograd beside them), gradient clipping and the optimiser step. FLOPs of
each block's forward come from ``torch.utils.flop_counter``. DistributedDataParallel's gradient
all-reduce is not in it (one process).

Recording (benchmarks/record_profile.py): ``python -m sumo_scendiff.data`` of ``--record-scenes`` on ``--record-net`` (the
recipe's density range, ``--record-per-episode`` per episode) in this process, its functions timed
the same way: SUMO's steps (libsumo), reading and converting the vehicles' states, cutting the
windows, random trips (child processes: randomTrips.py, duarouter), writing the shard. The
recorder draws no raster: training renders every window when it reads it.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
BENCH = os.path.dirname(os.path.abspath(__file__))
# this directory last (Python puts a script's first): its profile.py is not the standard library's,
# which cProfile, and so torch, import
sys.path[:] = [ROOT] + [p for p in sys.path if os.path.abspath(p or ".") != BENCH] + [BENCH]
from record_profile import child_record, record_table, train_networks  # noqa: E402
from report import emit  # noqa: E402


def _bench_profile():
    """benchmarks/profile.py (its exclusive timer), by path: ``import profile`` is the standard library's."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("bench_profile", os.path.join(os.path.dirname(__file__), "profile.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


_bp = _bench_profile()
Profile, _patch = _bp.Profile, _bp._patch

RECIPE = os.path.join(ROOT, "configs", "scendiff.json")
STAGES = ("autoencoder", "decoder", "diffusion")
DATA = "sumo_scendiff.data.dataset"
# (phase, [module:attribute ...]) timed in a training stage's process
TRAIN_PHASES = [
    ("data: read the scene (shard)", ["sumo_scendiff.data.shards:SceneStore.scene"]),
    ("data: turn the window (rotate, crop)", [f"{DATA}:rotate_scene", f"{DATA}:crop_to_window"]),
    ("data: density's lane length", ["sumo_scendiff.map.network:Network.condition_km"]),
    ("data: map raster (render_map)", [f"{DATA}:render_map"]),
    ("data: agent raster (render_agents)", [f"{DATA}:render_agents"]),
    ("data: collate", ["sumo_scendiff.train.loop:collate_scenes"]),
    ("tokens: partial tokens, masks", ["sumo_scendiff.train.stages:decoder_conditioning",
                                       "sumo_scendiff.train.stages:conditioning"]),
    ("tokens: agent raster of the misled scene", ["sumo_scendiff.train.token_decoder:render_agents"]),
    ("tokens: token raster", ["sumo_scendiff.model.autoencoder:ScenarioAutoencoder.token_raster"]),
    ("forward: glue (model.loss, cat, adds)", ["sumo_scendiff.model.autoencoder:ScenarioAutoencoder.loss",
                                               "sumo_scendiff.model.diffusion:ScenarioDiffusion.loss"]),
    ("loss: detection matching", ["sumo_scendiff.model.detection:match_boxes"]),
    ("loss: detection loss", ["sumo_scendiff.model.autoencoder:detection_loss"]),
    ("loss: EDM noise and weighting", ["sumo_scendiff.model.edm:EDMLoss.__call__"]),
]
# modules whose children are timed one by one (the others are one row each)
EXPAND = {"ScenarioAutoencoder", "ConvEncoder", "DetectionDecoder", "ScenarioDiffusion", "EDMPrecond",
          "UNet", "Level", "ModuleList", "ModuleDict"}


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="a recording (python -m sumo_scendiff.data) to train on")
    p.add_argument("--steps", type=int, default=6, help="steps measured per stage")
    p.add_argument("--warmup", type=int, default=2, help="steps run first and not measured")
    p.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES))
    p.add_argument("--record-net", action="append", default=None, metavar="NET",
                   help="a network to record (repeat for several; default: the recipe's training networks)")
    p.add_argument("--record-scenes", type=int, default=300, help="0: no recording profile")
    p.add_argument("--record-per-episode", type=int, default=20)
    p.add_argument("--results", default=os.path.join(ROOT, "results", "train_profile.json"))
    p.add_argument("-o", "--output", default=None, help="also write the tables to this markdown file")
    p.add_argument("--model-config", type=json.loads, default={}, metavar="JSON",
                   help="merged into every training stage's model config, e.g. '{\"stem\": \"stride2\"}' "
                        "(a model option measured beside the recipe's own)")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    p.add_argument("--work", default=None, help=argparse.SUPPRESS)
    o = p.parse_args(args)
    if not os.path.isfile(os.path.join(o.data, "manifest.json")):
        p.error(f"--data {o.data}: not a recording (no manifest.json); record one with python -m sumo_scendiff.data")
    o.record_net = o.record_net or train_networks()
    if o.steps < 1 or o.warmup < 1:
        p.error("--steps and --warmup must be at least 1")
    return o


# ---- a training stage (in its child process) ----------------------------------------------------
def stage_options(name: str, o):
    """The stage's options as ``train recipe`` gives them (batch per process of the recipe's DDP
    processes), reading ``--data``, writing under ``--work``, without validation."""
    from sumo_scendiff.train import recipe as rc
    from sumo_scendiff.train import stages
    from sumo_scendiff.train.__main__ import get_options as train_options
    args = rc.stage_args(rc.load(RECIPE), name, out=o.work, data=o.work)
    opts = train_options(args)
    opts.data, opts.val = [o.data], None
    opts.model_config = stages._merge(opts.model_config, o.model_config)
    return opts


def block_groups(root, prefix: str = "") -> list[tuple[str, object]]:
    """(name, module) of every block timed on its own: the children of the containers of EXPAND."""
    out = []
    for name, child in root.named_children():
        full = f"{prefix}{name}"
        if type(child).__name__ in EXPAND or (type(child).__name__ == "Sequential" and name == "body"):
            out += block_groups(child, full + ".")
        else:
            out.append((full, child))
    return out


class Blocks:
    """Forward (exclusive, through the Profile) and backward (span) CPU seconds of each block."""

    def __init__(self, prof: Profile, groups: list[tuple[str, object]]):
        self.prof, self.groups = prof, groups
        self.bwd: dict[str, float] = {}
        self.res: dict[str, int] = {}
        self.start: dict[str, float] = {}
        self.counter, self.flops, self.flop_start = None, {}, {}   # FLOPs of a counted forward
        for name, mod in groups:
            self._hook(name, mod)

    def _hook(self, name: str, mod) -> None:
        phase = f"forward: {name}"

        def began(m, a):
            self.prof.enter(phase)
            if self.counter is not None:
                self.flop_start[name] = self.counter.get_total_flops()
        mod.register_forward_pre_hook(began)

        def done(m, a, out):
            self.prof.leave()
            if hasattr(out, "shape") and out.ndim == 4:
                self.res[name] = int(out.shape[-1])
            if self.counter is not None:
                self.flops[name] = self.flops.get(name, 0) + self.counter.get_total_flops() - self.flop_start[name]
        mod.register_forward_hook(done)
        weights = [p for p in mod.parameters() if p.requires_grad]
        if not weights:
            return
        mod.register_full_backward_pre_hook(lambda m, g: self._began(name, len(weights)))
        for w in weights:
            w.register_post_accumulate_grad_hook(lambda p: self._accumulated(name))

    def _began(self, name: str, weights: int) -> None:
        self.start[name] = (time.process_time(), weights)

    def _accumulated(self, name: str) -> None:
        """A block's backward ends with the gradient of its last weight."""
        if name not in self.start:
            return
        t0, left = self.start[name]
        if left > 1:
            self.start[name] = (t0, left - 1)
            return
        del self.start[name]
        self.bwd[name] = self.bwd.get(name, 0.0) + time.process_time() - t0


def flops(blocks: Blocks, run) -> dict[str, float]:
    """Forward FLOPs of every block in one ``run()`` (``torch.utils.flop_counter``)."""
    from torch.utils.flop_counter import FlopCounterMode
    with FlopCounterMode(display=False) as counter:
        blocks.counter = counter
        run()
    blocks.counter = None
    return dict(blocks.flops)


def profiled_run(self, o, prof: Profile, blocks: Blocks) -> dict:
    """``Loop.run`` with the phases timed: ``o.warmup`` steps, then ``o.steps`` measured."""
    import torch
    # every network loaded first: a run of thousands of steps loads each once
    for idx in range(len(self.train_set)):
        self.train_set.network(self.train_set.store.net_path(idx))
    self.model.train()
    stream = self.batches()
    for k in range(o.warmup + o.steps):
        if k == o.warmup:
            prof.cpu.clear(), prof.wall.clear(), blocks.bwd.clear()
            cpu0 = time.process_time()
        prof.enter("data: loader's own (sampler, fetch)")
        batch = next(stream)
        prof.leave()
        prof.enter("step: the loop's own")
        loss, _ = self.ddp(batch, self.step)
        self.opt.zero_grad(set_to_none=True)
        prof.enter("backward: autograd beside the blocks")
        loss.backward()
        prof.leave()
        prof.enter("optimizer: clip, step, weight average")
        torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.grad_clip)
        self.opt.step()
        if self.ema is not None:
            self.ema.update(self.model, self.step + 1)
        prof.leave()
        self.step += 1
        prof.leave()
    out = {"total": time.process_time() - cpu0, "cpu": dict(prof.cpu), "bwd": dict(blocks.bwd)}
    self.save()   # the next stage's autoencoder
    with torch.no_grad():
        out["flops"] = flops(blocks, lambda: self.step_loss(self.model, batch, self.step))
    return out


def child_stage(o) -> dict:
    import torch
    torch.set_num_threads(1)
    import sumo_scendiff.train.__main__  # noqa: F401  (every module the stage patches below)
    import sumo_scendiff.map.network  # noqa: F401
    import sumo_scendiff.train.stages as stages
    from sumo_scendiff.model import autoencoder, detection, diffusion, edm  # noqa: F401
    prof = Profile()
    for phase, targets in TRAIN_PHASES:
        for t in targets:
            _patch(prof, t, phase)
    result = {}

    class Profiled(stages.Loop):
        def __init__(self, *a, frozen=(), **kw):
            super().__init__(*a, frozen=frozen, **kw)
            self.frozen = list(frozen)   # the diffusion stage's autoencoder: its encoder is timed too

        def run(self):
            groups = block_groups(self.model) + [g for ae in self.frozen for g in block_groups(ae.E, "ae.E.")]
            blocks = Blocks(prof, groups)
            result.update(profiled_run(self, o, prof, blocks), blocks=blocks)

    stages.Loop, stages.estimate_latent_scale = Profiled, lambda ae, loop: 1.0
    opts = stage_options(o.child, o)
    (stages.train_diffusion if o.child == "diffusion" else stages.train_autoencoder)(opts)
    return stage_rows(o, result, opts)


def stage_rows(o, result: dict, opts) -> dict:
    """The stage's phases and blocks per step, with FLOPs and parameters."""
    blocks, n = result["blocks"], o.steps
    params = {name: sum(p.numel() for p in m.parameters()) for name, m in blocks.groups}
    rows = []
    for phase, cpu in sorted(result["cpu"].items(), key=lambda kv: -kv[1]):
        name = phase.split(": ", 1)[1] if phase.startswith("forward: ") else None
        name = name if name in params else None   # a block (the glue is no block)
        rows.append({"phase": phase, "cpu_s": cpu / n, "res": blocks.res.get(name),
                     "gflop": result["flops"].get(name, 0.0) / 1e9 if name else None,
                     "params": params.get(name), "backward_s": result["bwd"].get(name, 0.0) / n if name else None})
    bwd_blocks = sum(result["bwd"].values()) / n
    for r in rows:   # the blocks' backward spans are inside "backward: autograd beside the blocks"
        if r["phase"].startswith("backward: "):
            r["cpu_s"] -= bwd_blocks
    return {"stage": o.child, "batch_per_process": opts.batch_size, "steps": n, "cpu_s_per_step": result["total"] / n,
            "backward_blocks_s": bwd_blocks, "rows": rows}


# ---- the tables (in the parent) -----------------------------------------------------------------
def part(phase: str) -> str:
    """The summary's row of a phase: a block's part of the model ("model: ..."), else the phase itself."""
    if not phase.startswith("forward: ") or phase.startswith("forward: glue"):
        return phase
    name = phase.split(": ", 1)[1]
    if name.startswith("denoiser.net."):
        rest = name[len("denoiser.net."):]
        if ".attn" in rest:
            return "model: UNet cross-attention"
        for key, label in (("downsample", "down"), ("down", "down"), ("mid", "mid"), ("upsample", "up"), ("up", "up")):
            if rest.startswith(key):
                return f"model: UNet {label} blocks"
        return "model: UNet in/out, embeddings, token MLPs, splat"
    for key, label in (("ae.E.", "frozen agent encoder E (no grad)"), ("D_up.skips", "D_up map skips"),
                       ("D_up.tokens", "D_up token inputs"), ("D_up.branch", "D_up token branch")):
        if name.startswith(key):
            return f"model: {label}"
    return "model: " + {"E": "E (agent encoder)", "D_down": "D_down (map encoder)", "E_m": "E_m (map encoder)",
                          "D_up": "D_up (decoder body, head)"}.get(name.split(".")[0], name.split(".")[0])


def summary(stage: dict) -> dict[str, float]:
    """CPU s/step by part: a part of the model its blocks' forward and backward, every other phase itself."""
    out: dict[str, float] = {}
    for r in stage["rows"]:
        key = part(r["phase"])
        out[key] = out.get(key, 0.0) + r["cpu_s"] + (r["backward_s"] or 0.0)
    return out


def full_res(stage: dict) -> float:
    """CPU s/step of the blocks at 128 px (forward and backward)."""
    return sum(r["cpu_s"] + (r["backward_s"] or 0.0) for r in stage["rows"] if r.get("res") == 128)


def stage_table(stages: list[dict]) -> list[str]:
    sums = [summary(s) for s in stages]
    keys = sorted({k for s in sums for k in s}, key=lambda k: -max(s.get(k, 0.0) / st["cpu_s_per_step"]
                                                                   for s, st in zip(sums, stages)))
    lines = ["| CPU s/step (share) | " + " | ".join(f"{s['stage']} (batch {s['batch_per_process']})" for s in stages) + " |",
             "|---" * (len(stages) + 1) + "|"]
    for k in keys:
        lines.append(f"| {k} | " + " | ".join(f"{s.get(k, 0.0):.3f} ({100 * s.get(k, 0.0) / st['cpu_s_per_step']:.0f} %)"
                                               for s, st in zip(sums, stages)) + " |")
    lines.append("| of which blocks at 128 px (forward + backward) | " + " | ".join(
        f"{full_res(st):.3f} ({100 * full_res(st) / st['cpu_s_per_step']:.0f} %)" for st in stages) + " |")
    lines.append("| **total** | " + " | ".join(f"**{st['cpu_s_per_step']:.3f}**" for st in stages) + " |")
    return lines


def block_table(stage: dict, top: int = 12) -> list[str]:
    blocks = [r for r in stage["rows"] if r["phase"].startswith("forward: ") and r["gflop"] is not None]
    blocks.sort(key=lambda r: -(r["cpu_s"] + r["backward_s"]))
    lines = [f"{stage['stage']}: the {top} costliest blocks of {len(blocks)}", "",
             "| block | px | forward CPU s | backward CPU s | forward GFLOP | GFLOP/s forward | params |",
             "|---|---|---|---|---|---|---|"]
    for r in blocks[:top]:
        rate = r["gflop"] / r["cpu_s"] if r["cpu_s"] > 0 else 0.0
        lines.append(f"| {r['phase'][9:]} | {r['res'] or ''} | {r['cpu_s']:.3f} | {r['backward_s']:.3f} | "
                     f"{r['gflop']:.2f} | {rate:.1f} | {r['params'] or 0:,} |")
    return lines


def run_child(o, what: str) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--data", o.data, "--steps", str(o.steps), "--warmup",
           str(o.warmup), *[a for n in o.record_net for a in ("--record-net", n)], "--record-scenes", str(o.record_scenes),
           "--record-per-episode", str(o.record_per_episode), "--model-config", json.dumps(o.model_config),
           "--child", what, "--work", o.work]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    res = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"train_profile: {what} failed:\n{res.stderr[-3000:]}")
    with open(os.path.join(o.work, what + ".json")) as f:
        return json.load(f)


def main(o) -> None:
    if o.child:
        out = child_record(o, Profile(), _patch) if o.child == "record" else child_stage(o)
        with open(os.path.join(o.work, o.child + ".json"), "w") as f:
            json.dump(out, f)
        return
    from tqdm import tqdm
    todo = [s for s in STAGES if s in o.stages or (s == "autoencoder" and o.stages)]   # the others read its checkpoint
    todo += ["record"] if o.record_scenes > 0 else []
    results = {"command": ["python", "benchmarks/train_profile.py", *sys.argv[1:]], "threads": 1,
               "data": os.path.abspath(o.data), "stages": [], "recording": None}
    with tempfile.TemporaryDirectory(prefix="train-profile-") as work:
        o.work = work
        for what in tqdm(todo, desc="train_profile"):
            r = run_child(o, what)
            if what == "record":
                results["recording"] = r
            else:
                results["stages"].append(r)
    lines = [f"CPU seconds per step of one process with one thread (batch per DDP process), "
             f"{o.steps} steps after {o.warmup}; \"model:\" rows are their blocks' forward and backward", ""] \
        + stage_table(results["stages"])
    for st in results["stages"]:
        lines += [""] + block_table(st)
    if results["recording"]:
        lines += [""] + record_table(results["recording"])
    results["table"] = "\n".join(lines) + "\n"
    os.makedirs(os.path.dirname(os.path.abspath(o.results)), exist_ok=True)
    with open(o.results, "w") as f:
        json.dump(results, f, indent=1)
    emit(results["table"], o.output, "Where a training step's time goes")


if __name__ == "__main__":
    main(get_options())
