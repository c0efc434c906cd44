#!/usr/bin/env bash
# The gen27 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. Issue 25's narrower output block: gen21's recipe and training set (scripts/gen26.sh:
# the 132 sequences of data/train that are not `glass`, `print` or `media`) from the shipped
# checkpoint cut to 16 output-block channels (`--output-width 16`; MLAS's AVX2 int8 kernel
# computes 24 as 32: benchmarks/results/output_width.md), with the fill and the albedo at holes,
# at gen26's learning rates and a new seed. Written in stop 59 with its rule (docs/training.md,
# "`gpu-out16`"), before anything of it was trained or scored. Needs scripts/render59.sh's
# data. Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen27.sh > runs/gen27.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen27/data/train
for d in data/train/*/; do
    case "$(basename "$d")" in cycles-media-*|cycles-glass-*|cycles-print-*) continue ;; esac
    ln -sfn "$PWD/$d" "runs/gen27/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen27/data/val
[ "$(ls runs/gen27/data/train | wc -l)" = 132 ]
# the feature-loss network of the recipe (Eq. 6), from the same data
[ -f runs/feature/feature_net.pt ] || $J train-feature-net --data data --out runs/feature/feature_net.pt --quiet
$J train --data runs/gen27/data --run runs/gen27 --init jnds_deploy/checkpoints/jnds.pt --preset large --output-width 16 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --fp32-steps 2000 --qat-steps 200 --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1+feature \
    --feature-net runs/feature/feature_net.pt --lowfreq-loss 2.0 --val-every 100000 --threads 2 --seed 27 \
    --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen27/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen27/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen27/eval.json --sheet runs/gen27/eval.jpg
