#!/usr/bin/env bash
# The gen33 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen31's run (issue 24's guide input on the cheap references) with the guide in use from
# the first step: `--guide-init split` halves the projection's albedo weights and gives the other
# half to the guide (from zero weights, gen31 left it unlearned), seed 33, from the checkpoint
# shipped when it starts (its output block width kept: gen32's 16 if that one shipped). Written
# in stop 64 with its rule (docs/training.md, "`gen33`"), before anything of it was trained or
# scored. Not beside gen32: the two runs would share the two cores (stop 65 runs it first,
# scripts/chain65.sh). Needs scripts/chain62.sh's data and the feature net it trained.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen33.sh > runs/gen33.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
PY=.venv/bin/python
mkdir -p runs/gen33/data/train
# the init, frozen at the first start: a model shipped while this runs changes nothing here
[ -f runs/gen33/init.pt ] || cp jnds_deploy/checkpoints/jnds.pt runs/gen33/init.pt
width=$($PY -c "import sys; from jnds_deploy.checkpoint import read_checkpoint
print(read_checkpoint(sys.argv[1])['model_config']['output_width'])" runs/gen33/init.pt)
for d in data/spp8/train/*/; do
    ln -sfn "$PWD/$d" "runs/gen33/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen33/data/val
[ "$(ls runs/gen33/data/train | wc -l)" = 132 ]
[ -f runs/feature-spp8/feature_net.pt ]
$J train --data runs/gen33/data --run runs/gen33 --init runs/gen33/init.pt --preset large --output-width "$width" \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --guide-albedo --guide-init split --clean-references oidn --fp32-steps 2000 --qat-steps 200 \
    --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 33 --exposure -4 8 --rotate-normals --flips --balance-renderers
# `gen33.sh train` stops here (added in stop 65, when the evaluation sets were rendered after it)
[ "${1:-}" = train ] && exit 0
[ -f runs/gen33/eval.json ] || $J evaluate --checkpoint runs/gen33/init.pt runs/gen33/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen33/eval.json --sheet runs/gen33/eval.jpg
