#!/usr/bin/env bash
# The gen30 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. Issue 24's guide input: gen26's run (gen21's recipe and training set: the 132 sequences
# of data/train that are not `glass`, `print` or `media`, from the shipped checkpoint, with the
# fill and the albedo at holes) with the network reading the guide albedo (`--guide-albedo`:
# Cycles' Denoising Albedo, the albedo on the Mitsuba sequences, which have none; the new
# weights start at 0, so step 0 is the shipped model), seed 30. Written in stop 61 with its rule
# (docs/training.md, "`gen30`"), before anything of it was trained or scored. Needs
# scripts/render59.sh's data. Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen30.sh > runs/gen30.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen30/data/train
for d in data/train/*/; do
    case "$(basename "$d")" in cycles-media-*|cycles-glass-*|cycles-print-*) continue ;; esac
    ln -sfn "$PWD/$d" "runs/gen30/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen30/data/val
[ "$(ls runs/gen30/data/train | wc -l)" = 132 ]
# the feature-loss network of the recipe (Eq. 6), from the same data
[ -f runs/feature/feature_net.pt ] || $J train-feature-net --data data --out runs/feature/feature_net.pt --quiet
$J train --data runs/gen30/data --run runs/gen30 --init jnds_deploy/checkpoints/jnds.pt --preset large \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --guide-albedo --fp32-steps 2000 --qat-steps 200 --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1+feature \
    --feature-net runs/feature/feature_net.pt --lowfreq-loss 2.0 --val-every 100000 --threads 2 --seed 30 \
    --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen30/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen30/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen30/eval.json --sheet runs/gen30/eval.jpg
