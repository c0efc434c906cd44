#!/usr/bin/env bash
# The gen37 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. Is the feature-loss network the fine-tune's cost? `gen34`'s command without the feature
# term (`--spatial-loss l1`: L1 and the low-frequency term, as before), the same seed (33: the same
# patches in the same order), data, init (runs/gen33/init.pt, the shipped `gen21`), steps and
# learning rates, so that `gen34` and it differ in the feature term alone. Written in stop 67 with
# its rules (docs/training.md, "`gen37`"), before any of it was trained or scored. Needs `gen34`'s
# run (its control). Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen37.sh > runs/gen37.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
[ -f runs/gen33/init.pt ] && [ -f runs/gen34/checkpoint.pt ]
mkdir -p runs/gen37/data/train
for d in data/spp8/train/*/; do
    ln -sfn "$PWD/$d" "runs/gen37/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen37/data/val
[ "$(ls runs/gen37/data/train | wc -l)" = 132 ]
$J train --data runs/gen37/data --run runs/gen37 --init runs/gen33/init.pt --preset large --output-width 24 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --clean-references oidn --fp32-steps 2000 --qat-steps 200 \
    --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1 --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 33 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ "${1:-}" = train ] && exit 0
# the three in one run: the init, the control, gen37
[ -f runs/gen37/eval.json ] || $J evaluate --checkpoint runs/gen33/init.pt runs/gen34/checkpoint.pt \
    runs/gen37/checkpoint.pt --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen37/eval.json --sheet runs/gen37/eval.jpg
