#!/usr/bin/env bash
# The shipped model's recipe (round 15, 1 h 31 min on the 2-core CPU): the architecture trained from
# scratch in one pass, on the project's own networks only (all 15 of networks/splits.json "train"),
# with none of round 14's warm-start history (scripts/train_recipe.sh, ~12 h 50 min). Resumable: run
# it again after an interruption.
#
#     scripts/train_fast.sh [OUT_DIR]        # default runs/fast; the model is OUT_DIR/scendiff.pt
#     AE_STEPS=3500 DECODER_STEPS=600 scripts/train_fast.sh runs/fast2   # other step budgets
#     PROCS=1 scripts/train_fast.sh          # one process (2 threads) instead of two
#
# The learning rate drops to a tenth at 85 % of each stage's steps, rounded down to a hundred. FAST_DATA (default data/fast) is
# where the recordings go; a run with other step budgets reuses them.
# Each training stage runs as PROCS (default 2) DistributedDataParallel processes of one thread each
# (torch.distributed.run, gloo), each on its share of the batch: on the 2-core CPU that is 1.2-1.6x the
# steps per second of one process with two threads (benchmarks/train_speed.py), for the same global batch.
# Times measured on the 2-core CPU are in README "Training" (with the model's numbers beside the
# shipped one's); each stage's start and end are appended to OUT_DIR/times.log.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-runs/fast}
DATA=${FAST_DATA:-data/fast}
AE_STEPS=${AE_STEPS:-5500}
DECODER_STEPS=${DECODER_STEPS:-2500}
DIFFUSION_STEPS=${DIFFUSION_STEPS:-3600}
PROCS=${PROCS:-2}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-$(( PROCS > 1 ? 1 : 2 ))}
if [ "$PROCS" -gt 1 ]; then
    TRAIN="python -m torch.distributed.run --standalone --nproc_per_node $PROCS -m sumo_scendiff.train"
else
    TRAIN="python -m sumo_scendiff.train"
fi
per_proc() { echo $(( $1 / PROCS )); }  # the global batch split over the processes
drop_at() { echo $(( $1 * 17 / 20 / 100 * 100 )); }  # 85 %, down to a hundred
mkdir -p "$OUT"
NETS=$(python -c "import json; print(' '.join('-n networks/' + n for n in json.load(open('networks/splits.json'))['train']))")
resume_flag() { [ -d "$1.partial" ] && echo --resume || true; }
stamp() { echo "$(date -u +%FT%TZ) $*" >> "$OUT/times.log"; }

# 1. Recordings (~6 min): dense random trips (40-800 veh/h/km of lane, 8 vehicles per window),
#    each window's circumscribed circle, so turned training windows are whole.
stamp record
[ -f $DATA/train/manifest.json ] || python -m sumo_scendiff.data $NETS -o $DATA/train --scenes 36000 -s 2 \
    --workers 2 --density 40 800 $(resume_flag $DATA/train)
[ -f $DATA/val/manifest.json ] || python -m sumo_scendiff.data $NETS -o $DATA/val --scenes 1200 -s 3 \
    --density 40 800 $(resume_flag $DATA/val)

# 2. The autoencoder with the shipped model's config (map skips, 19 map channels, MultiBin heading
#    head, KL weight 0.01, loss weights of steps 7 and 13 of the full recipe), AE_STEPS (5 500); then
#    its decoder alone on mu itself (latent_noise 0: what the diffusion model's latents are),
#    DECODER_STEPS (2 500).
stamp autoencoder
AE_CONFIG='{"C_m": 19, "map_skips": true, "heading_bins": 16, "kl_weight": 0.01, "loss": {"category_weights":
    [1.0, 1.0, 4.0], "box_weight": 4.0, "vertex_weight": 2.0, "heading_bin_weight": 2.0}}'
$TRAIN autoencoder --data $DATA/train --val $DATA/val -o "$OUT/ae" --steps $AE_STEPS \
    --batch-size $(per_proc 16) --lr 5e-4 --lr-drop-at $(drop_at $AE_STEPS) --model-config "$AE_CONFIG"
stamp decoder
$TRAIN autoencoder --data $DATA/train --val $DATA/val -o "$OUT/ae_mu" \
    --init-from "$OUT/ae/last.pt" --freeze-encoder --steps $DECODER_STEPS --batch-size $(per_proc 16) --lr 1e-4 \
    --lr-drop-at $(drop_at $DECODER_STEPS) \
    --model-config '{"latent_noise": 0}'

# 3. The diffusion model in that latent space, DIFFUSION_STEPS (3 600) at batch 32, noise levels shifted up
#    (log sigma ~ N(0.3, 1.4^2): the map-only sampler otherwise loses agents at high sigma), 30 % of
#    the examples without tokens and 20 % with every agent a token.
stamp diffusion
$TRAIN diffusion --autoencoder "$OUT/ae/last.pt" --data $DATA/train --val $DATA/val \
    -o "$OUT/diffusion" --batch-size $(per_proc 32) --val-batches 4 --steps $DIFFUSION_STEPS --lr 6e-4 \
    --lr-drop-at $(drop_at $DIFFUSION_STEPS) \
    --model-config '{"P_mean": 0.3, "P_std": 1.4}' --p-keep-all-tokens 0.2 --p-map-only 0.3

# 4. Export, calibrate the global token's guidance on turned validation windows, export again.
stamp export
MODEL="$OUT/scendiff.pt"
python -m sumo_scendiff.train export --autoencoder "$OUT/ae_mu/last.pt" --diffusion "$OUT/diffusion/last.pt" \
    -o "$MODEL" --fp16 --force --scene-guidance-sigma 1
W=$(python benchmarks/scene_guidance.py --checkpoint "$MODEL" --data $DATA/val --turned | grep -o "at w = [0-9.]*" \
    | grep -o "[0-9.]*$" | xargs printf "%.1f")
python -m sumo_scendiff.train export --autoencoder "$OUT/ae_mu/last.pt" --diffusion "$OUT/diffusion/last.pt" \
    -o "$MODEL" --fp16 --force --scene-guidance "$W" --scene-guidance-sigma 1
stamp done "scene guidance $W"
