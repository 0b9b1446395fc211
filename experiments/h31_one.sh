#!/bin/bash
# h31_one.sh TAG NETPATH WINDOWS SCENES [args]: one net, with events
cd /work/h31 && export PYTHONPATH=/work/h31
TAG=$1; NET=$2; W=$3; SC=$4; shift 4
python benchmarks/seeding.py -n $NET --windows $W --checkpoint runs/signals/scendiff.pt --scenes $SC --events runs/h31/$TAG.events.pkl -o runs/h31/$TAG.md "$@" > runs/h31/$TAG.log 2>&1
grep -A2 "\*\*all\|^| [a-z_0-9]* | SUMO | [0-9]* | [0-9]" runs/h31/$TAG.md | grep -v Lane | tail -4
