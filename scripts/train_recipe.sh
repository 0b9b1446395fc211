#!/usr/bin/env bash
# The recipe that produces the shipped checkpoint sumo_scendiff/weights/scendiff.pt from a fresh clone,
# using only the project's own generated networks (networks/splits.json "train").
# Every step is resumable: run the script again after an interruption and it continues.
# About 2 hours of training on an idle 2-core CPU plus ~5 minutes of recording (see README "Training").
set -euo pipefail
cd "$(dirname "$0")/.."
TRAIN_NETS=$(python -c "import json; print(' '.join('-n networks/' + n for n in json.load(open('networks/splits.json'))['train']))")
AE_STEPS=${AE_STEPS:-4978}      # ~70 min at ~0.8 s/step (batch 16), KL weight 0.1 (the paper's)
DIFF_STEPS=${DIFF_STEPS:-2179}  # ~50 min at ~1.3 s/step (batch 32)
AE2_STEPS=${AE2_STEPS:-7700}    # the autoencoder continued to this step at KL weight 0.01, ~35 min
DIFF2_STEPS=${DIFF2_STEPS:-1600}  # diffusion with the token splat, warm-started from the first, ~40 min
DIFF3_STEPS=${DIFF3_STEPS:-1900}  # ... then at a tenth of the learning rate, ~7 min

resume_flag() { [ -d "$1.partial" ] && echo --resume || true; }
[ -f data/train/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/train --scenes 36000 -s 0 --workers 2 $(resume_flag data/train)
[ -f data/val/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/val --scenes 1200 -s 1 $(resume_flag data/val)

python -m sumo_scendiff.train autoencoder --data data/train --val data/val -o runs/ae --steps "$AE_STEPS"
python -m sumo_scendiff.train diffusion --autoencoder runs/ae/last.pt --data data/train --val data/val \
    -o runs/diffusion --steps "$DIFF_STEPS" --batch-size 32 --lr 6e-4 --val-batches 4 \
    --model-config '{"unet": {"splat_ch": 0}}'
python -m sumo_scendiff.train export --autoencoder runs/ae/last.pt --diffusion runs/diffusion/last.pt \
    -o sumo_scendiff/weights/scendiff.pt --fp16 --force   # the shipped checkpoint (round 2)

[ "${ROUND3:-0}" = 1 ] || exit 0
# Round 3 (ROUND3=1): the KL term at 0.1 left the latent too noisy at agent cells to place boxes precisely
# (posterior std 0.58 against |mu| 0.94; reconstruction F1 0.66, benchmarks/reconstruction.py), so
# the autoencoder continues at 0.01 (its plateau schedule drops the learning rate to 3e-5 at
# step 7 500, which took reconstruction F1 from 0.66 to 0.85); the diffusion model gains the token
# splat (model/unet.py), is warm-started from round 2 on the new latent and ends at a tenth of
# its learning rate.
[ -d runs/ae_kl01 ] || { mkdir -p runs/ae_kl01 && cp runs/ae/last.pt runs/ae_kl01/last.pt; }
python -m sumo_scendiff.train autoencoder --data data/train --val data/val -o runs/ae_kl01 \
    --steps "$AE2_STEPS" --model-config '{"kl_weight": 0.01}'
python -m sumo_scendiff.train diffusion --autoencoder runs/ae_kl01/last.pt --data data/train --val data/val \
    -o runs/diffusion_splat --init-from runs/diffusion/last.pt --steps "$DIFF2_STEPS" --batch-size 32 \
    --lr 6e-4 --val-batches 4
python -m sumo_scendiff.train diffusion --autoencoder runs/ae_kl01/last.pt --data data/train --val data/val \
    -o runs/diffusion_splat --steps "$DIFF3_STEPS" --batch-size 32 --lr 6e-5 --val-batches 4
python -m sumo_scendiff.train export --autoencoder runs/ae_kl01/last.pt --diffusion runs/diffusion_splat/last.pt \
    -o runs/scendiff_r3.pt --fp16 --force   # the round-3 candidate (README "Round 3"), not shipped
