#!/usr/bin/env bash
# The gen21 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen19's recipe, seed and init (scripts/gen19.sh: gen14 fine-tuned 2200 steps, the
# low-frequency term at weight 2.0) on gen19's training set grown by the 16 sequences of the
# Cycles `layers` kind (scripts/render53.sh, rendered here first where missing): a data
# experiment with gen19 as its control. Started in stop 53; chosen over the shipped gen19 (`jnds`
# in the evaluation) only by the rule written then (docs/training.md, "gen21").
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen21.sh > runs/gen21.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
bash scripts/render53.sh
mkdir -p runs/gen21
# gen14, the init of gen16-gen21: the shipped checkpoint before stop 51
[ -f runs/gen21/gen14.pt ] || git show a60bb20:jnds_deploy/checkpoints/jnds.pt > runs/gen21/gen14.pt
$J train --data data --run runs/gen21 --init runs/gen21/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --fp32-steps 2000 --qat-steps 200 --lr 2e-4 \
    --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen21/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen21/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 --out runs/gen21/eval.json \
    --sheet runs/gen21/eval.jpg
