#!/usr/bin/env bash
# The gen26 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. The shipped model (gen21 with the diffuse fill) trained longer: gen21's recipe and
# training set (scripts/gen21.sh: the 132 sequences of data/train that are not `glass`,
# `print` or `media`, linked into runs/gen26/data) from gen21's weights, with the fill, at half
# the learning rate and a new seed, as gen6 and gen9 were their parents trained longer.
# Written in stop 57 with its rule (docs/training.md, "gen26"), before anything of it was
# trained or scored. Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen26.sh > runs/gen26.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen26/data/train
for d in data/train/*/; do
    case "$(basename "$d")" in cycles-media-*|cycles-glass-*|cycles-print-*) continue ;; esac
    ln -sfn "$PWD/$d" "runs/gen26/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen26/data/val
[ "$(ls runs/gen26/data/train | wc -l)" = 132 ]
# the init: the checkpoint shipped in stop 56 (gen21's weights, diffuse_fill on)
[ -f runs/gen26/init.pt ] || git show cd3ec45:jnds_deploy/checkpoints/jnds.pt > runs/gen26/init.pt
$J train --data runs/gen26/data --run runs/gen26 --init runs/gen26/init.pt --preset large --fixed-upsample \
    --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill --fp32-steps 2000 \
    --qat-steps 200 --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt \
    --lowfreq-loss 2.0 --val-every 100000 --threads 2 --seed 26 --exposure -4 8 --rotate-normals --flips \
    --balance-renderers
[ -f runs/gen26/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen26/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen26/eval.json --sheet runs/gen26/eval.jpg
