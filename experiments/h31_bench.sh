#!/bin/bash
# usage: h31_bench.sh TAG [extra args]   -> runs/h31/TAG_8.md and TAG_16.md (sequential, same cached scenes)
set -e
cd /work/h31
export PYTHONPATH=/work/h31
TAG=$1; shift
S=../shared/nets
python benchmarks/seeding.py --windows 8 --checkpoint runs/signals/scendiff.pt --scenes runs/h31/scenes17.pkl -o runs/h31/${TAG}_8.md "$@" > runs/h31/${TAG}_8.log 2>&1
python benchmarks/seeding.py -n $S/resco_cologne1/cologne1.net.xml -n $S/resco_cologne3/cologne3.net.xml -n $S/resco_cologne8/cologne8.net.xml -n $S/resco_ingolstadt1/ingolstadt1.net.xml -n $S/resco_ingolstadt7/ingolstadt7.net.xml -n $S/resco_ingolstadt21/ingolstadt21.net.xml -n $S/berlin_doerpfeldstr/net.net.xml.gz --windows 16 --checkpoint runs/signals/scendiff.pt --scenes runs/h31/scenes17_16.pkl -o runs/h31/${TAG}_16.md "${@//_8.events/_16.events}" > runs/h31/${TAG}_16.log 2>&1
