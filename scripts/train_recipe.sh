#!/usr/bin/env bash
# The recipe that produces the shipped checkpoint sumo_scendiff/weights/scendiff.pt from a fresh clone,
# using only the project's own generated networks (networks/splits.json "train").
# Every step is resumable: run the script again after an interruption and it continues.
# About 12 h 50 min of training on a 2-core CPU plus ~55 minutes of recording (docs/training.md).
set -euo pipefail
cd "$(dirname "$0")/.."
# Steps 1-13 record squares (--square, the format those rounds trained on); step 14 records each
# window's circumscribed circle, so that turned training windows are whole.
# networks/splits.json "train": its first 12 networks feed steps 1-10; the 3 added later (curved
# streets, turn lanes, uneven junction angles) are recorded in step 11 for the decoder.
TRAIN_NETS=$(python -c "import json; print(' '.join('-n networks/' + n for n in json.load(open('networks/splits.json'))['train'][:12]))")
ADDED_NETS=$(python -c "import json; print(' '.join('-n networks/' + n for n in json.load(open('networks/splits.json'))['train'][12:]))")
# Steps 1-10 read the first 11 map channels (C_m 11: the map raster before the lane-direction
# histogram of step 12); warm starts and continuations keep their source's.
SIGMA='{"P_mean": 0.0, "P_std": 1.4, "C_m": 11}'  # training noise levels shifted up from the paper's -0.5 / 1

resume_flag() { [ -d "$1.partial" ] && echo --resume || true; }
SHIPPED=sumo_scendiff/weights/scendiff.pt
# export_calibrated AE DIFFUSION [CALIBRATION OPTIONS]: export to $SHIPPED, then calibrate the global
# token's guidance weight (applied above sigma 1) on validation windows into it (train calibrate with
# the options given; default: the dense validation recording)
export_calibrated() {
    python -m sumo_scendiff.train export --autoencoder "$1" --diffusion "$2" -o $SHIPPED --fp16 --force \
        --scene-guidance-sigma 1
    python -m sumo_scendiff.train calibrate --model $SHIPPED --data data/val_dense "${@:3}"
}
[ -f data/train/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/train --scenes 36000 -s 0 --workers 2 --square $(resume_flag data/train)
[ -f data/val/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/val --scenes 1200 -s 1 --square $(resume_flag data/val)

# 1. The autoencoder, 7 700 steps (~110 min at ~0.85 s/step, batch 16). KL weight 0.1 (the paper's)
#    to step 4 978, then 0.01 in a copy: at 0.1 the latent is too noisy at agent cells to place boxes
#    (posterior std 0.58 against |mu| 0.94, reconstruction F1 0.66; experiments/reconstruction.py).
#    The learning rate drops to a tenth at step 7 500, which took reconstruction F1 to 0.85.
python -m sumo_scendiff.train autoencoder --data data/train --val data/val -o runs/ae --steps 4978 \
    --lr-drop-at 7500 --model-config '{"C_m": 11}'
[ -d runs/ae_kl01 ] || { mkdir -p runs/ae_kl01 && cp runs/ae/last.pt runs/ae_kl01/last.pt; }
python -m sumo_scendiff.train autoencoder --data data/train --val data/val -o runs/ae_kl01 --steps 7700 \
    --lr-drop-at 7500 --model-config '{"kl_weight": 0.01}'

# 2. The diffusion model with the token splat, 4 200 steps (~90 min at ~1.3 s/step, batch 32), EMA
#    weights exported. It loses agents between sigma 2 and 20 (experiments/reconstruction.py "from the
#    data at sigma"), and log sigma ~ N(-0.5, 1) puts 12 % of its steps above sigma 2: from step 1 300 the noise
#    levels are N(0, 1.4^2). Map-only generation then still made half the agents; the last 600 steps
#    give 30 % of the examples no token at all (p_mask = 1) and 20 % every token (the paper: 0 % / 40 %).
DIFF="python -m sumo_scendiff.train diffusion --autoencoder runs/ae_kl01/last.pt --data data/train --val data/val
      -o runs/diffusion_r4 --batch-size 32 --val-batches 4"
$DIFF --steps 1300 --lr 6e-4 --lr-drop-at 3000 --model-config '{"C_m": 11}'
$DIFF --steps 3600 --lr 6e-4 --lr-drop-at 3000 --model-config "$SIGMA"
$DIFF --steps 4200 --lr 2e-4 --lr-drop-at 4000 --model-config "$SIGMA" --p-keep-all-tokens 0.2 --p-map-only 0.3

# 4. Denser traffic for the diffusion model: the recordings above average 4.0 vehicles per window,
#    the real cities 7.0; at 40-800 veh/h/km they average 8.0. 2 400 steps from the step-4 200 weight
#    average (~55 min), same latent space and scale.
[ -f data/train_dense/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/train_dense --scenes 36000 -s 2 \
    --workers 2 --density 40 800 --square $(resume_flag data/train_dense)
[ -f data/val_dense/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/val_dense --scenes 1200 -s 3 \
    --density 40 800 --square $(resume_flag data/val_dense)
python -m sumo_scendiff.train diffusion --autoencoder runs/ae_kl01/last.pt --data data/train_dense \
    --val data/val_dense -o runs/diffusion_r5 --init-from runs/diffusion_r4/last.pt --batch-size 32 \
    --val-batches 4 --steps 2400 --lr 2e-4 --lr-drop-at 2000 --model-config "$SIGMA" \
    --p-keep-all-tokens 0.2 --p-map-only 0.3

# 5. 3 200 steps more on the denser set from that weight average (~60 min); the lr drops at 2 700.
python -m sumo_scendiff.train diffusion --autoencoder runs/ae_kl01/last.pt --data data/train_dense \
    --val data/val_dense -o runs/diffusion_r6 --init-from runs/diffusion_r5/last.pt --batch-size 32 \
    --val-batches 4 --steps 3200 --lr 2e-4 --lr-drop-at 2700 --model-config "$SIGMA" \
    --p-keep-all-tokens 0.2 --p-map-only 0.3

# 6. 3 000 steps more from that weight average with the noise levels shifted further up (log sigma ~
#    N(0.3, 1.4^2)): the map-only sampler lost agents at high sigma (README "How the shipped checkpoint
#    was found"); ~65 min; the lr drops at 2 400.
python -m sumo_scendiff.train diffusion --autoencoder runs/ae_kl01/last.pt --data data/train_dense \
    --val data/val_dense -o runs/diffusion_r7 --init-from runs/diffusion_r6/last.pt --batch-size 32 \
    --val-batches 4 --steps 3000 --lr 2e-4 --lr-drop-at 2400 --model-config '{"P_mean": 0.3, "P_std": 1.4, "C_m": 11}' \
    --p-keep-all-tokens 0.2 --p-map-only 0.3

# 7. A second autoencoder, from scratch on the denser recording, 7 700 steps (~2 h 10 min at ~1 s/step):
#    KL weight 0.01 from the start, trajectory weights 1 / 1 / 4, 4x box, 2x vertex weight. The first
#    one's encoder carried no speed: a probe re-rendered at 0.2x / 1.5x its speed decoded to the same
#    speed (experiments/token_response.py --autoencoder: response 0.00), so no diffusion model trained in
#    its latent space could follow a speed token. This one's: 0.82.
python -m sumo_scendiff.train autoencoder --data data/train_dense --val data/val_dense -o runs/ae_v2 \
    --steps 7700 --lr-drop-at 7000 --model-config '{"C_m": 11, "kl_weight": 0.01, "loss": {"category_weights":
    [1.0, 1.0, 4.0], "box_weight": 4.0, "vertex_weight": 2.0}}'

# 8. Its decoder alone on the latents the diffusion model learns (mu itself: latent_noise 0, no
#    reparameterisation noise), 1 000 steps (~17 min): reconstruction F1 0.939 -> 0.977, median heading
#    error 0.069 -> 0.031 rad, speed MAE 1.85 -> 0.46 m/s. Then 1 200 steps with D_down's 32 / 64 px map
#    features added into the decoder (map skips, zero-initialised; ~20 min).
python -m sumo_scendiff.train autoencoder --data data/train_dense --val data/val_dense \
    -o runs/ae_v2_mu0 --init-from runs/ae_v2/last.pt --freeze-encoder --steps 1000 --lr 1e-4 \
    --lr-drop-at 800 --model-config '{"latent_noise": 0}'
python -m sumo_scendiff.train autoencoder --data data/train_dense --val data/val_dense \
    -o runs/ae_v2_skips --init-from runs/ae_v2_mu0/last.pt --freeze-encoder --steps 1200 --lr 1e-4 \
    --lr-drop-at 1000 --model-config '{"map_skips": true}'

# 9. The diffusion model in the new latent space, 2 700 steps (~60 min at ~1.3 s/step), warm-started
#    from step 6's weight average (its map encoder and token path; the latent scale is re-estimated);
#    the lr drops at 2 300.
python -m sumo_scendiff.train diffusion --autoencoder runs/ae_v2/last.pt --data data/train_dense \
    --val data/val_dense -o runs/diffusion_v2 --init-from runs/diffusion_r7/last.pt --batch-size 32 \
    --val-batches 4 --steps 2700 --lr 3e-4 --lr-drop-at 2300 --model-config '{"P_mean": 0.3, "P_std": 1.4, "C_m": 11}' \
    --p-keep-all-tokens 0.2 --p-map-only 0.3

# 10. Export, calibrate the global token's guidance (applied above sigma = 1) on the dense validation
#    windows (the weight where map-only generation draws as many vehicles as the ground truth), stored
#    in the exported file (~3 min).
export_calibrated runs/ae_v2_skips/last.pt runs/diffusion_v2/last.pt

# 11. The decoder alone once more (encoder frozen: the same latent space, so the diffusion model and its
#     latent scale stay valid), 800 steps (~25 min) from the round-9 export on the dense recording plus
#     a recording of the three networks added to the training split (curvy_town, organic_turnlanes,
#     grid_turnlanes_tls: 12 000 + 300 scenes at 40-800 veh/h/km, ~25 min). Then export it with the
#     round-9 diffusion model, recalibrate the global token's guidance into it (~5 min).
[ -f data/train_organic/manifest.json ] || python -m sumo_scendiff.data $ADDED_NETS -o data/train_organic --scenes 12000 \
    -s 4 --workers 2 --density 40 800 --square $(resume_flag data/train_organic)
[ -f data/val_organic/manifest.json ] || python -m sumo_scendiff.data $ADDED_NETS -o data/val_organic --scenes 300 -s 5 \
    --density 40 800 --square $(resume_flag data/val_organic)
# the decoder-only runs of steps 11-13 train on the dense recording plus the added networks' one
DECODER_DATA="--data data/train_dense data/train_organic --val data/val_dense data/val_organic"
R9=runs/scendiff_r9.pt   # step 10's export, kept: the diffusion model and encoder of round 11
[ -f $R9 ] || cp $SHIPPED $R9
python -m sumo_scendiff.train autoencoder --init-from $R9 --freeze-encoder $DECODER_DATA -o runs/ae_r11a \
    --steps 800 --lr 1e-4 --lr-drop-at 650
export_calibrated runs/ae_r11a/last.pt $R9

# 12. The decoder alone with the lane-direction histogram (map channels lane_dir000..lane_dir315,
#     C_m 19; their weights in D_down start at zero): 1 000 steps (~21 min) from step 11's export on the
#     same data, lr 1.5e-4, then 1.5e-5 from 800. The diffusion model keeps reading the first 11
#     channels. Export, recalibrate the global token's guidance into it (~5 min).
R11=runs/scendiff_r11.pt   # step 11's export: the diffusion model and encoder of round 12
[ -f $R11 ] || cp $SHIPPED $R11
python -m sumo_scendiff.train autoencoder --init-from $R11 --freeze-encoder $DECODER_DATA -o runs/ae_r12a \
    --steps 1000 --lr 1.5e-4 --lr-drop-at 800 --model-config '{"C_m": 19}'
export_calibrated runs/ae_r12a/last.pt $R11

# 13. The decoder with a MultiBin heading head (heading_bins 16: a logit and a residual angle per
#     22.5-degree bin, 32 output channels that start at zero; model/heading.py), encoder frozen:
#     1 000 steps from step 12's export (lr 1.5e-4, then 1.5e-5 from 800; ~22 min), then 1 500 more
#     with the bin cross-entropy weighted 2 (lr 1.5e-4, then 1.5e-5 from 1 200; ~35 min). Export with
#     the same diffusion model, recalibrate the global token's guidance into it (~5 min).
R12=runs/scendiff_r12.pt   # step 12's export: the diffusion model and encoder of round 13
[ -f $R12 ] || cp $SHIPPED $R12
python -m sumo_scendiff.train autoencoder --init-from $R12 --freeze-encoder $DECODER_DATA -o runs/ae_r13_head \
    --steps 1000 --lr 1.5e-4 --lr-drop-at 800 --model-config '{"heading_bins": 16}'
python -m sumo_scendiff.train autoencoder --init-from runs/ae_r13_head/last.pt --freeze-encoder $DECODER_DATA \
    -o runs/ae_r13_head2 --steps 1500 --lr 1.5e-4 --lr-drop-at 1200 --model-config '{"loss": {"heading_bin_weight": 2.0}}'
export_calibrated runs/ae_r13_head2/last.pt $R12

# 14. The diffusion model once more, on a recording of circles (each window's circumscribed circle,
#     the data CLI's default since round 14): the dense recording of step 4 again (same seeds, same
#     windows and instants; cropped to its squares it is step 4's recording exactly), now with the
#     vehicles that a turned window's corners hold. Steps 1-13 trained on turned windows whose
#     corners were empty, and the model put 3-5 % of its agents beyond 50 m from the centre where
#     SUMO has 8-13 %. 1 500 steps from step 13's export (its latent space and scale; lr 2e-4, then
#     2e-5 from 1 200; ~55 min), export with step 13's autoencoder, recalibrate.
#     The calibration now uses turned windows of the circle recording (as training and the
#     evaluation see them): on the axis-aligned windows of steps 10-13 this model draws far fewer
#     agents (2.9 against 4.0 per window at w = 1) and would get w = 1.8; on turned ones, 1.4.
R13=runs/scendiff_r13.pt   # step 13's export: the autoencoder of round 14
[ -f $R13 ] || cp $SHIPPED $R13
[ -f data/train_dense_disc/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/train_dense_disc \
    --scenes 36000 -s 2 --workers 2 --density 40 800 $(resume_flag data/train_dense_disc)
[ -f data/val_dense_disc/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/val_dense_disc \
    --scenes 1200 -s 3 --density 40 800 $(resume_flag data/val_dense_disc)
python -m sumo_scendiff.train diffusion --autoencoder $R13 --init-from $R13 --data data/train_dense_disc \
    --val data/val_dense_disc -o runs/diffusion_r14disc --batch-size 32 --val-batches 4 --steps 1500 \
    --lr 2e-4 --lr-drop-at 1200 --p-keep-all-tokens 0.2 --p-map-only 0.3
export_calibrated $R13 runs/diffusion_r14disc/last.pt --data data/val_dense_disc --turned
