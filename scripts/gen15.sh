#!/usr/bin/env bash
# The gen15 run from wherever it stopped (docs/training.md, "gen15"), unattended: every step
# resumes or is skipped when done, so on a fresh machine (after `make setup`) or after the
# session that ran it ended, the same command goes on. In order: the rest of gen14's
# training set (Mitsuba then Cycles), the feature-loss network, gen15's training from the
# shipped gen14, then the test and holdout splits, and gen14 against gen15 on val, test and
# holdout (the choice is made on validation: a tie in stop 49, gen15 not shipped,
# docs/training.md). The validation split is rendered first.
# Run it in its own session, niced, e.g.
#   setsid nohup bash scripts/gen15.sh > runs/gen15.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
$J dataset --out data --split val --jobs 2
$J dataset --out data --split val --engine cycles --jobs 2
$J dataset --out data --split train --train-sequences 24 --moving-sequences 8 --jobs 2
$J dataset --out data --split train --engine cycles --train-sequences 8 --mixed-sequences 24 \
    --lights-sequences 24 --interior-sequences 12 --jobs 2
[ -f runs/feature/feature_net.pt ] || $J train-feature-net --data data --out runs/feature/feature_net.pt
mkdir -p runs/gen15
[ -f runs/gen15/gen14.pt ] || cp jnds_deploy/checkpoints/jnds.pt runs/gen15/gen14.pt
$J train --data data --run runs/gen15 --init runs/gen15/gen14.pt --preset deep --deepen-blend -2 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 \
    --fp32-steps 2200 --qat-steps 200 --lr 2e-4 --qat-lr 4e-5 --warmup-steps 100 \
    --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --val-every 100000 \
    --threads 2 --seed 19 --exposure -4 8 --rotate-normals --flips --colours --balance-renderers
$J dataset --out data --split test --jobs 2
$J dataset --out data --split test --engine cycles --jobs 2
$J dataset --out data --split holdout --engine cycles --jobs 2
[ -f runs/gen15/eval.json ] || $J evaluate --checkpoint runs/gen15/gen14.pt runs/gen15/checkpoint.pt \
    --data data/val data/test data/holdout --baselines bicubic oidn-balanced --threads 2 \
    --out runs/gen15/eval.json --sheet runs/gen15/eval.jpg
