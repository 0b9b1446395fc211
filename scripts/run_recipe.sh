#!/usr/bin/env bash
# Run a training recipe (configs/*.json) stage by stage. Resumable: run it again after an
# interruption and every stage continues where it stopped (a complete recording is skipped).
#
#     scripts/run_recipe.sh RECIPE.json OUT [DATA_DIR] [--steps STAGE=N ...]
#
# OUT is {out} in the recipe, DATA_DIR {data}. Training stages run as PROCS (default: the recipe's
# "procs") DistributedDataParallel processes of one thread each (torch.distributed.run, gloo), each on
# its share of the global batch; one process runs with two threads. Each stage's start is appended to
# OUT/times.log (beside OUT when OUT is a file name).
set -euo pipefail
cd "$(dirname "$0")/.."
RECIPE=$1
OUT=$2
DATA=${3:-}
EXTRA=("${@:4}")
recipe() { python -m sumo_scendiff.train recipe "$RECIPE" --out "$OUT" ${DATA:+--data-dir "$DATA"} "$@"; }
PROCS=${PROCS:-$(recipe --print procs)}
THREADS=${OMP_NUM_THREADS:-$(( PROCS > 1 ? 1 : 2 ))}
if [ "$PROCS" -gt 1 ]; then
    TRAIN=(python -m torch.distributed.run --standalone --nproc_per_node "$PROCS" -m sumo_scendiff.train)
else
    TRAIN=(python -m sumo_scendiff.train)
fi
case "$OUT" in *.pt) LOG=${OUT%.pt}.times.log ;; *) mkdir -p "$OUT"; LOG=$OUT/times.log ;; esac
stamp() { echo "$(date -u +%FT%TZ) $*" >> "$LOG"; }

STAGES=$(recipe --print stages)
for STAGE in $STAGES; do
    LINES=$(recipe --print-stage "$STAGE" --procs "$PROCS" "${EXTRA[@]}")
    [ -n "$LINES" ] || continue   # a recording that is already complete
    mapfile -t ARGS <<< "$LINES"
    stamp "$STAGE"
    case "${ARGS[0]}" in
        data) python -m sumo_scendiff.data "${ARGS[@]:1}" ;;
        autoencoder|diffusion) OMP_NUM_THREADS=$THREADS "${TRAIN[@]}" "${ARGS[@]}" ;;
        *) python -m sumo_scendiff.train "${ARGS[@]}" ;;
    esac
done
stamp done
