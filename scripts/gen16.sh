#!/usr/bin/env bash
# The gen16 run from wherever it stopped (docs/training.md, "gen16"), unattended; every step
# resumes or is skipped when done. gen14's training set (scripts/gen15.sh renders it) grown by
# 16 sequences of the Cycles `detail` kind, gen14 fine-tuned on it with gen14's recipe, the
# choice made on validation (stop 50: worse there, not shipped; docs/training.md, "gen16"); then
# the test split and the holdout, and both models scored there, for the record.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen16.sh > runs/gen16.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
$J dataset --out data --split test --jobs 2
$J dataset --out data --split train --engine cycles --train-sequences 8 --detail-sequences 16 --jobs 2
mkdir -p runs/gen16
[ -f runs/gen16/gen14.pt ] || cp jnds_deploy/checkpoints/jnds.pt runs/gen16/gen14.pt
$J train --data data --run runs/gen16 --init runs/gen16/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --fp32-steps 2000 --qat-steps 200 --lr 2e-4 \
    --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --val-every 100000 \
    --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen16/eval_val.json ] || $J evaluate --checkpoint runs/gen16/gen14.pt runs/gen16/checkpoint.pt \
    --data data/val --baselines bicubic oidn-balanced --threads 2 --out runs/gen16/eval_val.json \
    --sheet runs/gen16/eval_val.jpg
$J dataset --out data --split test --engine cycles --jobs 2
[ -f runs/gen16/eval_test.json ] || $J evaluate --checkpoint runs/gen16/gen14.pt runs/gen16/checkpoint.pt \
    --data data/test --baselines bicubic oidn-balanced --threads 2 --out runs/gen16/eval_test.json \
    --sheet runs/gen16/eval_test.jpg
$J dataset --out data --split holdout --engine cycles --jobs 2
[ -f runs/gen16/eval_holdout.json ] || $J evaluate --checkpoint runs/gen16/gen14.pt runs/gen16/checkpoint.pt \
    --data data/holdout --baselines bicubic oidn-balanced --threads 2 --out runs/gen16/eval_holdout.json \
    --sheet runs/gen16/eval_holdout.jpg
