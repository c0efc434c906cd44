#!/usr/bin/env bash
# The gen17 run from wherever it stopped (docs/training.md, "gen17"), unattended; every step
# resumes or is skipped when done. gen16's recipe, data and seed (scripts/gen16.sh) with one
# change: the low-frequency loss term (--lowfreq-loss, training.losses.lowfreq), so that gen16
# is its paired control. Then gen14 (shipped), gen16 and gen17 scored on the first holdout, the
# selection set for unseen kinds (docs/model-gap.md, "Since gen14"), and on validation. Stop 51:
# chosen there and shipped (docs/training.md, "gen17"), then scored once on holdout2 (docs/model-gap.md).
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen17.sh > runs/gen17.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen17
[ -f runs/gen17/gen14.pt ] || cp jnds_deploy/checkpoints/jnds.pt runs/gen17/gen14.pt
$J train --data data --run runs/gen17 --init runs/gen17/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --fp32-steps 2000 --qat-steps 200 --lr 2e-4 \
    --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --lowfreq-loss 0.5 \
    --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --balance-renderers
for split in holdout val; do
    [ -f runs/gen17/eval_$split.json ] || $J evaluate --checkpoint runs/gen17/gen14.pt runs/gen16/checkpoint.pt \
        runs/gen17/checkpoint.pt --data data/$split --baselines bicubic oidn-balanced --threads 2 \
        --out runs/gen17/eval_$split.json --sheet runs/gen17/eval_$split.jpg
done
