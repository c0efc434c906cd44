#!/usr/bin/env bash
# The gen29 run from wherever it stopped, unattended. gen28 (scripts/gen28.sh) went on with the
# whole network trainable: the U-Net may now adapt its features to the 16-channel output block
# (the GPU fine-tunes of stop 59 trained every weight), on the same inputs and teacher, the
# spatial terms weighted as much as the temporal one (--w-spatial 0.5; the recipe's 0.2 weighs
# the temporal term 0.8), at half gen28's learning rate. Needs gen28's checkpoint (runs/gen28,
# not in git) and data/distill. Written in stop 60 with its rule (docs/training.md, "gen29"),
# before anything of it was trained or scored. Run it alone: nothing heavy beside it.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
[ "$(ls data/distill/train | wc -l)" = 132 ]
$J train --data data/distill --run runs/gen29 --init runs/gen28/checkpoint.pt \
    --teacher jnds_deploy/checkpoints/jnds.pt --preset large --output-width 16 --w-spatial 0.5 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --fp32-steps 0 --qat-steps 400 --qat-lr 5e-5 --lowfreq-loss 2.0 --val-every 100000 \
    --threads 2 --seed 29 --exposure -4 8 --rotate-normals --flips --balance-renderers --quiet
for set in val media; do
    [ -f runs/gen29/eval_$set.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt \
        runs/gen28/checkpoint.pt runs/gen29/checkpoint.pt --data data/$set --baselines oidn-balanced --threads 2 \
        --out runs/gen29/eval_$set.json --sheet runs/gen29/eval_$set.jpg
done
