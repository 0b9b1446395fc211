#!/usr/bin/env bash
# The shipped model's recipe, configs/fast.json (round 15, 1 h 31 min on the 2-core CPU): the
# architecture trained from scratch in one pass, on the project's own networks only (all 15 of
# networks/splits.json "train"), with none of round 14's warm-start history (scripts/train_recipe.sh,
# ~12 h 50 min). Resumable: run it again after an interruption.
#
#     scripts/train_fast.sh [OUT_DIR]        # default runs/fast; the model is OUT_DIR/scendiff.pt
#     AE_STEPS=3500 DECODER_STEPS=600 scripts/train_fast.sh runs/fast2   # other step budgets
#     PROCS=1 scripts/train_fast.sh          # one process (2 threads) instead of two
#
# 1. Recordings (~6 min): dense random trips (40-800 veh/h/km of lane, 8 vehicles per window), each
#    window's circumscribed circle, so turned training windows are whole. FAST_DATA (default
#    data/fast) is where they go; a run with other step budgets reuses them.
# 2. The autoencoder (map skips, 19 map channels, MultiBin heading head, KL weight 0.01, loss weights
#    of steps 7 and 13 of the full recipe), AE_STEPS (5 500); then its decoder alone on mu itself
#    (latent_noise 0: what the diffusion model's latents are), DECODER_STEPS (2 500).
# 3. The diffusion model in that latent space, DIFFUSION_STEPS (3 600) at batch 32, noise levels
#    shifted up (log sigma ~ N(0.3, 1.4^2): the map-only sampler otherwise loses agents at high
#    sigma), 30 % of the examples without tokens and 20 % with every agent a token.
# 4. Export, then calibrate the global token's guidance on turned validation windows into the model.
#
# The learning rate drops to a tenth at 85 % of each stage's steps, rounded down to a hundred. Each
# training stage runs as two one-thread DistributedDataParallel processes, each on its share of the
# batch: on the 2-core CPU that is 1.2-1.6x the steps per second of one process with two threads
# (benchmarks/train_speed.py), for the same global batch. Times measured on the 2-core CPU are in
# docs/training.md; each stage's start is appended to OUT_DIR/times.log.
set -euo pipefail
cd "$(dirname "$0")/.."
exec scripts/run_recipe.sh configs/fast.json "${1:-runs/fast}" "${FAST_DATA:-data/fast}" \
    ${AE_STEPS:+--steps autoencoder=$AE_STEPS} ${DECODER_STEPS:+--steps decoder=$DECODER_STEPS} \
    ${DIFFUSION_STEPS:+--steps diffusion=$DIFFUSION_STEPS}
