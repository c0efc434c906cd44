#!/usr/bin/env bash
# gen40: the shipped checkpoint with the space-to-depth input block, fitted to the shipped input
# block's features, then distilled from the shipped model with the rest of the network frozen.
# Written in stop 73 with its rule (docs/training.md, "`gen40`"), before any of it ran. Resumes
# from its checkpoint (every 100 steps); the score (no baselines: runs/gen39/eval.json has them on
# the same sets) is skipped once written. Run it niced:
#   (setsid nohup bash -c 'echo $$ > /tmp/gen40.sid; exec nice bash scripts/gen40.sh' >> runs/gen40.log 2>&1 &)
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
SHIPPED=jnds_deploy/checkpoints/jnds.pt
mkdir -p runs/gen40/data/train
for d in data/spp8/train/*/; do
    ln -sfn "$PWD/$d" "runs/gen40/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen40/data/val
[ "$(ls runs/gen40/data/train | wc -l)" = 132 ]
[ -f runs/feature-spp8/feature_net.pt ]
$J train --data runs/gen40/data --run runs/gen40 --init $SHIPPED --teacher $SHIPPED --preset large \
    --input-block space_to_depth --input-hidden 32 --input-fit-steps 1500 --train-only network.input_block \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --fp32-steps 0 --qat-steps 1200 --qat-lr 1e-4 \
    --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 40 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ "${1:-}" = train ] && exit 0
[ -f runs/gen40/eval.json ] || $J evaluate --checkpoint $SHIPPED runs/gen40/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 --out runs/gen40/eval.json --sheet runs/gen40/eval.jpg
# the rule's time clause (appended in stop 73 while it trained, so the running script reads it at
# its end): both int8 pipelines exported and calibrated by today's code, timed one after the other
for m in shipped gen40; do
    ck=$SHIPPED; [ $m = gen40 ] && ck=runs/gen40/checkpoint.pt
    [ -f runs/gen40/timing-$m.json ] || { $J export --checkpoint $ck --out runs/gen40/artifacts-$m &&
        $J calibrate --artifacts runs/gen40/artifacts-$m --data samples/orbit-160x90 --method qat &&
        .venv/bin/python benchmarks/timing.py --artifacts runs/gen40/artifacts-$m --precisions int8 \
            --out runs/gen40/timing-$m; }
done
