#!/usr/bin/env bash
# The gen34 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. `gen33`'s control: `gen33`'s command without the guide input (no `--guide-albedo`, no
# `--guide-init`), the same seed (33), data and init (`gen33`'s frozen `runs/gen33/init.pt`, the
# shipped `gen21`). `gen33` and it differ only in the guide, so their scores on the holdouts
# separate what the guide adds from what the recipe's fine-tune costs (docs/training.md,
# "`gen34`"). Written in stop 65 with its rule, before any of it ran. Needs `gen33`'s run, the
# cheap-reference training set and its feature net, and the three evaluation sets to score.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen34.sh > runs/gen34.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
[ -f runs/gen33/checkpoint.pt ] && [ -f runs/gen33/init.pt ]
mkdir -p runs/gen34/data/train
for d in data/spp8/train/*/; do
    ln -sfn "$PWD/$d" "runs/gen34/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen34/data/val
[ "$(ls runs/gen34/data/train | wc -l)" = 132 ]
[ -f runs/feature-spp8/feature_net.pt ]
$J train --data runs/gen34/data --run runs/gen34 --init runs/gen33/init.pt --preset large --output-width 24 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --clean-references oidn --fp32-steps 2000 --qat-steps 200 \
    --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 33 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ "${1:-}" = train ] && exit 0
# the three in one run: the init, the guide, its control
[ -f runs/gen34/eval.json ] || $J evaluate --checkpoint runs/gen33/init.pt runs/gen33/checkpoint.pt \
    runs/gen34/checkpoint.pt --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen34/eval.json --sheet runs/gen34/eval.jpg
