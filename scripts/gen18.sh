#!/usr/bin/env bash
# The gen18 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen17's recipe, data and seed (scripts/gen17.sh) with the low-frequency loss term at
# twice the weight (--lowfreq-loss 1.0): gen16 (no term), gen17 (0.5) and gen18 (1.0) are the
# same batches in the same order, a dose-response of the term (`jnds` in its evaluations is
# the shipped gen17). Started at the end of stop 51 and run again from gen14 in stop 52; chosen
# there on both holdouts together and shipped (docs/training.md, "gen18 and soups";
# scripts/soups52.sh scored the candidates).
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen18.sh > runs/gen18.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen18
# gen14, the init of gen16 and gen17: the shipped checkpoint before stop 51
[ -f runs/gen18/gen14.pt ] || git show a60bb20:jnds_deploy/checkpoints/jnds.pt > runs/gen18/gen14.pt
$J train --data data --run runs/gen18 --init runs/gen18/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --fp32-steps 2000 --qat-steps 200 --lr 2e-4 \
    --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --lowfreq-loss 1.0 \
    --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --balance-renderers
for split in holdout val; do
    [ -f runs/gen18/eval_$split.json ] || $J evaluate --checkpoint runs/gen18/gen14.pt \
        jnds_deploy/checkpoints/jnds.pt runs/gen18/checkpoint.pt --data data/$split --baselines bicubic oidn-balanced --threads 2 \
        --out runs/gen18/eval_$split.json --sheet runs/gen18/eval_$split.jpg
done
