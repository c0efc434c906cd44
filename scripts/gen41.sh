#!/usr/bin/env bash
# gen41: gen40 distilled 1200 QAT steps more from the shipped model (a warm restart of its
# learning rate), the same design, data, teacher and frozen rest. Written in stop 73 with its rule
# (docs/training.md, "`gen41`"), after gen40 was scored and before any of this ran. Resumes from its
# checkpoint; the score is skipped once written. Run it niced:
#   (setsid nohup bash -c 'echo $$ > /tmp/gen41.sid; exec nice bash scripts/gen41.sh' >> runs/gen41.log 2>&1 &)
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
SHIPPED=jnds_deploy/checkpoints/jnds.pt
[ -f runs/gen40/checkpoint.pt ] && [ -d runs/gen40/data/train ]
[ -f runs/feature-spp8/feature_net.pt ]
$J train --data runs/gen40/data --run runs/gen41 --init runs/gen40/checkpoint.pt --teacher $SHIPPED --preset large \
    --input-block space_to_depth --input-hidden 32 --train-only network.input_block \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --fp32-steps 0 --qat-steps 1200 --qat-lr 1e-4 \
    --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 41 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ "${1:-}" = train ] && exit 0
[ -f runs/gen41/eval.json ] || $J evaluate --checkpoint $SHIPPED runs/gen41/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 --out runs/gen41/eval.json --sheet runs/gen41/eval.jpg
