#!/usr/bin/env bash
# Stop 59: the evaluation and training data of the shipped model on this machine again
# (docs/dataset.md, the commands at its top), in the order the next steps need them: the
# validation splits, the two holdouts that choose a model, the sixth `media` sequence, then
# gen21's training set. Every command
# resumes where a previous run stopped; run it niced in its own session, e.g.
#   setsid nohup nice bash scripts/render59.sh >> runs/render59.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}
$J dataset --out data --split val --engine mitsuba
$J dataset --out data --split val --engine cycles
$J dataset --out data --split holdout --engine cycles
$J dataset --out data --split holdout2 --engine cycles
$J dataset --out data --split media --engine cycles --jobs 1
$J dataset --out data --split train --train-sequences 24 --moving-sequences 8 --jobs 2
$J dataset --out data --split train --engine cycles --train-sequences 8 --mixed-sequences 24 \
    --lights-sequences 24 --interior-sequences 12 --detail-sequences 16 --layers-sequences 16 --jobs 2
