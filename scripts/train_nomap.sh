#!/usr/bin/env bash
# The paper's no-map ablation of the shipped model (README "Evaluation", no-map row): the same model
# with the map taken away from both of its parts, fine-tuned to live without it. ~50 min on an idle
# 2-core CPU; needs data/train_dense and data/val_dense (scripts/train_recipe.sh records them).
# Every step is resumable: run the script again after an interruption and it continues.
#
#   scripts/train_nomap.sh [OUT.pt]        # default runs/scendiff_nomap.pt, then:
#   python -m sumo_scendiff.evaluate --scenes 200 --no-map-checkpoint runs/scendiff_nomap.pt
set -euo pipefail
cd "$(dirname "$0")/.."
SHIPPED=sumo_scendiff/weights/scendiff.pt
OUT=${1:-runs/scendiff_nomap.pt}

# 1. The diffusion model with the map input zeroed, 800 steps from the shipped weights (~30 min):
#    the same training as the shipped model's last stage (noise levels, token mix), lr drop at 650.
python -m sumo_scendiff.train diffusion --no-map --autoencoder $SHIPPED --init-from $SHIPPED \
    --data data/train_dense --val data/val_dense -o runs/diffusion_nomap --batch-size 32 --val-batches 4 \
    --steps 800 --lr 2e-4 --lr-drop-at 650 --model-config '{"P_mean": 0.3, "P_std": 1.4}' \
    --p-keep-all-tokens 0.2 --p-map-only 0.3

# 2. The detection decoder D(z, m) without the map (its encoder, and so the latent space, frozen),
#    1 000 steps (~20 min): in the paper's ablation nothing sees the map; a decoder that does would
#    still put the boxes on the lanes.
python -m sumo_scendiff.train autoencoder --no-map --freeze-encoder --init-from $SHIPPED \
    --data data/train_dense --val data/val_dense -o runs/ae_nomap --steps 1000 --lr 3e-4 --lr-drop-at 800 \
    --model-config '{"latent_noise": 0}'

# 3. Export, calibrate the global token's guidance as for the shipped model, export again.
python -m sumo_scendiff.train export --autoencoder runs/ae_nomap/last.pt --diffusion runs/diffusion_nomap/last.pt \
    -o "$OUT" --fp16 --force --scene-guidance-sigma 1
W=$(python benchmarks/scene_guidance.py --checkpoint "$OUT" | grep -o "at w = [0-9.]*" | grep -o "[0-9.]*$" \
    | xargs printf "%.1f")
python -m sumo_scendiff.train export --autoencoder runs/ae_nomap/last.pt --diffusion runs/diffusion_nomap/last.pt \
    -o "$OUT" --fp16 --force --scene-guidance "$W" --scene-guidance-sigma 1
