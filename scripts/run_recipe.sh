#!/usr/bin/env bash
# Run a training recipe (configs/*.json) stage by stage into OUT: the same as
#
#     python -m sumo_scendiff.train recipe RECIPE.json OUT [--data-dir DIR] [--scale toy] [--steps STAGE=N ...]
#
#     scripts/run_recipe.sh configs/scendiff.json runs/scendiff   # the shipped model from nothing (about 2 h 35 min)
#
# Resumable: run it again after an interruption and every stage continues where it stopped (a
# complete recording or a finished stage is skipped). OUT/recipe.json logs each stage's command and
# wall time, the commit and the model's SHA-256; PROCS=1 trains in one two-thread process instead of
# the recipe's one-thread DDP processes.
set -euo pipefail
cd "$(dirname "$0")/.."
exec python -m sumo_scendiff.train recipe "$1" "$2" ${PROCS:+--procs "$PROCS"} "${@:3}"
