#!/usr/bin/env bash
# Stop 62: what the next sessions on this machine run, in order, unattended, each step resuming
# where it stopped (a session's background processes die with it: start this again in the next).
# It replaces scripts/chain61.sh: gen21's training set with cheap references (8 samples per
# target pixel, cleaned by OIDN in training) costs about a tenth of the 64-spp one's ten-odd hours
# here and trains as well (docs/dataset.md, "Cheap references"). In order: that training set,
# `gen31`'s training (docs/training.md), the second holdout (its `street` references take
# minutes a frame; gen31's rule needs them), `gen31`'s scores, then the sixth `media` sequence
# (it chooses nothing). Each training run has the two cores alone (docs/dataset.md: a render
# beside it slows it many times). Run it in its own session, niced:
#   setsid nohup nice bash scripts/chain62.sh >> runs/chain62.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}
$J dataset --out data/spp8 --split train --reference-spp 8 --train-sequences 24 --moving-sequences 8 --jobs 2
$J dataset --out data/spp8 --split train --reference-spp 8 --engine cycles --train-sequences 8 \
    --mixed-sequences 24 --lights-sequences 24 --interior-sequences 12 --detail-sequences 16 \
    --layers-sequences 16 --jobs 2
bash scripts/gen31.sh
$J dataset --out data --split holdout2 --engine cycles
bash scripts/gen31.sh eval
$J dataset --out data --split media --engine cycles --jobs 1
