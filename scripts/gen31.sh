#!/usr/bin/env bash
# The gen31 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen30's run (issue 24's guide input: gen26's recipe from the shipped checkpoint with
# `--guide-albedo`) on gen21's 132 training sequences rendered with cheap references (8 samples
# per target pixel, cleaned by OIDN as `--clean-references oidn` cleans them: docs/dataset.md,
# "Cheap references"), seed 31. Written in stop 62 with its rule (docs/training.md, "`gen31`"),
# before anything of it was trained or scored. Needs scripts/chain62.sh's data. `gen31.sh`
# trains, then scores it against the shipped model on the first holdout and validation (two of
# its rule's clauses, while holdout2 is still rendering); `gen31.sh eval` scores it on both
# holdouts and validation, the whole rule, once holdout2 is rendered.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen31.sh > runs/gen31.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
if [ "${1:-}" = eval ]; then
    [ "$(ls -d data/holdout/*/sequence.json data/holdout2/*/sequence.json | wc -l)" = 12 ]
    [ -f runs/gen31/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen31/checkpoint.pt \
        --data data/holdout data/holdout2 data/val --baselines --threads 2 \
        --out runs/gen31/eval.json --sheet runs/gen31/eval.jpg
    exit 0
fi
mkdir -p runs/gen31/data/train
for d in data/spp8/train/*/; do
    ln -sfn "$PWD/$d" "runs/gen31/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen31/data/val
[ "$(ls runs/gen31/data/train | wc -l)" = 132 ]
# the feature-loss network of the recipe (Eq. 6), from the same references, cleaned
[ -f runs/feature-spp8/feature_net.pt ] || $J train-feature-net --data data/spp8 --clean-references oidn \
    --out runs/feature-spp8/feature_net.pt --quiet
$J train --data runs/gen31/data --run runs/gen31 --init jnds_deploy/checkpoints/jnds.pt --preset large \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --guide-albedo --clean-references oidn --fp32-steps 2000 --qat-steps 200 --lr 1e-4 \
    --qat-lr 2e-5 --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 31 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen31/eval-holdout-val.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt \
    runs/gen31/checkpoint.pt --data data/holdout data/val --baselines --threads 2 --out runs/gen31/eval-holdout-val.json
