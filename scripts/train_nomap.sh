#!/usr/bin/env bash
# The paper's no-map ablation of the shipped model, configs/nomap.json (docs/evaluation.md, no-map
# row): the same model with the map taken away from both of its parts, fine-tuned to live without
# it. ~50 min on an idle 2-core CPU; needs data/train_dense and data/val_dense (scripts/train_recipe.sh
# records them). Resumable: run it again after an interruption.
#
#   scripts/train_nomap.sh [OUT.pt]        # default runs/scendiff_nomap.pt, then:
#   python -m sumo_scendiff.evaluate --scenes 200 --no-map-checkpoint runs/scendiff_nomap.pt
#
# 1. The diffusion model with the map input zeroed, 800 steps from the shipped weights (~30 min):
#    the same training as the shipped model's last stage (noise levels, token mix), lr drop at 650.
# 2. The detection decoder D(z, m) without the map (its encoder, and so the latent space, frozen),
#    1 000 steps (~20 min): in the paper's ablation nothing sees the map; a decoder that does would
#    still put the boxes on the lanes.
# 3. Export, calibrate the global token's guidance into it as for the shipped model.
set -euo pipefail
cd "$(dirname "$0")/.."
exec scripts/run_recipe.sh configs/nomap.json "${1:-runs/scendiff_nomap.pt}"
