#!/usr/bin/env bash
# The recipe that produces the shipped checkpoint sumo_scendiff/weights/scendiff.pt from a fresh clone,
# using only the project's own generated networks (networks/splits.json "train").
# Every step is resumable: run the script again after an interruption and it continues.
# About 2 hours of training on an idle 2-core CPU plus ~5 minutes of recording (see README "Training").
set -euo pipefail
cd "$(dirname "$0")/.."
TRAIN_NETS=$(python -c "import json; print(' '.join('-n networks/' + n for n in json.load(open('networks/splits.json'))['train']))")
AE_STEPS=${AE_STEPS:-4978}      # ~70 min at ~0.8 s/step (batch 16)
DIFF_STEPS=${DIFF_STEPS:-2179}  # ~50 min at ~1.3 s/step (batch 32)

resume_flag() { [ -d "$1.partial" ] && echo --resume || true; }
[ -f data/train/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/train --scenes 36000 -s 0 --workers 2 $(resume_flag data/train)
[ -f data/val/manifest.json ] || python -m sumo_scendiff.data $TRAIN_NETS -o data/val --scenes 1200 -s 1 $(resume_flag data/val)

python -m sumo_scendiff.train autoencoder --data data/train --val data/val -o runs/ae --steps "$AE_STEPS"
python -m sumo_scendiff.train diffusion --autoencoder runs/ae/last.pt --data data/train --val data/val \
    -o runs/diffusion --steps "$DIFF_STEPS" --batch-size 32 --lr 6e-4 --val-batches 4
python -m sumo_scendiff.train export --autoencoder runs/ae/last.pt --diffusion runs/diffusion/last.pt \
    -o sumo_scendiff/weights/scendiff.pt --fp16 --force
