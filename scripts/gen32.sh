#!/usr/bin/env bash
# The gen32 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. Issue 25's narrower output block (`gen27`, written in stop 59) on the cheap references
# `gen31` trains on: gen31's command with `--output-width 16`, from the checkpoint shipped when
# it starts (gen31's if gen31's rule shipped it, with its guide input; else gen21's, without),
# seed 32. Start it only after gen31's verdict. Written in stop 63 with its rule
# (docs/training.md, "`gen32`"), before anything of it was trained or scored. Needs
# scripts/chain62.sh's data and gen31's feature net.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen32.sh > runs/gen32.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
PY=.venv/bin/python
mkdir -p runs/gen32/data/train
# the init, frozen at the first start: a model shipped while this runs changes nothing here
[ -f runs/gen32/init.pt ] || cp jnds_deploy/checkpoints/jnds.pt runs/gen32/init.pt
guide=$($PY -c "import sys; from jnds_deploy.checkpoint import read_checkpoint
print('--guide-albedo' if read_checkpoint(sys.argv[1])['model_config'].get('guide_albedo') else '')" runs/gen32/init.pt)
for d in data/spp8/train/*/; do
    ln -sfn "$PWD/$d" "runs/gen32/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen32/data/val
[ "$(ls runs/gen32/data/train | wc -l)" = 132 ]
[ -f runs/feature-spp8/feature_net.pt ]
$J train --data runs/gen32/data --run runs/gen32 --init runs/gen32/init.pt --preset large --output-width 16 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes $guide --clean-references oidn --fp32-steps 2000 --qat-steps 200 --lr 1e-4 \
    --qat-lr 2e-5 --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 32 --exposure -4 8 --rotate-normals --flips --balance-renderers
# `gen32.sh train` stops here (added in stop 65, when the evaluation sets were rendered after it)
[ "${1:-}" = train ] && exit 0
[ -f runs/gen32/eval.json ] || $J evaluate --checkpoint runs/gen32/init.pt runs/gen32/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen32/eval.json --sheet runs/gen32/eval.jpg
