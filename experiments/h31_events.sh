#!/bin/bash
# usage: h31_events.sh TAG [extra args]: both samples with --events runs/h31/TAG_{8,16}.events.pkl
cd /work/h31 && export PYTHONPATH=/work/h31
TAG=$1; shift
experiments/h31_bench.sh ${TAG} --events runs/h31/${TAG}_8.events.pkl "$@"
