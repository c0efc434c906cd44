#!/usr/bin/env bash
# The gen38 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. Capacity (docs/training.md, "`gen38`"): `gen34`'s command with the `wide` preset
# (`large` with the second encoder block 96 wide and the bottleneck 192), widened from the same
# init (`runs/gen33/init.pt`, the shipped `gen21`; `jnds train --init` embeds it so the wider
# network starts computing what it did), the same seed (33: the same patches in the same order),
# data (the 132 cheap-reference sequences), steps and learning rates. `gen34` is its control.
# Written in stop 68 with its rule, before any of it ran. Run it in its own session, niced, e.g.
#   (setsid nohup bash -c 'echo $$ > /tmp/gen38.sid; exec nice bash scripts/gen38.sh' >> runs/gen38.log 2>&1 &)
# Pause it with `pkill -STOP -s $(cat /tmp/gen38.sid)`, go on with -CONT.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
[ -f runs/gen33/init.pt ] && [ -f runs/gen34/checkpoint.pt ]
mkdir -p runs/gen38/data/train
for d in data/spp8/train/*/; do
    ln -sfn "$PWD/$d" "runs/gen38/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen38/data/val
[ "$(ls runs/gen38/data/train | wc -l)" = 132 ]
[ -f runs/feature-spp8/feature_net.pt ]
$J train --data runs/gen38/data --run runs/gen38 --init runs/gen33/init.pt --preset wide --output-width 24 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --clean-references oidn --fp32-steps 2000 --qat-steps 200 \
    --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 33 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ "${1:-}" = train ] && exit 0
# the three in one run: the init, the control, the wider network
[ -f runs/gen38/eval.json ] || $J evaluate --checkpoint runs/gen33/init.pt runs/gen34/checkpoint.pt \
    runs/gen38/checkpoint.pt --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen38/eval.json --sheet runs/gen38/eval.jpg
