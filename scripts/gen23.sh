#!/usr/bin/env bash
# The gen23 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen22's recipe, seed and init (scripts/gen22.sh: gen14 fine-tuned 2200 steps, the
# low-frequency term at weight 2.0) on gen22's training set grown by 8 sequences of the Cycles
# kind `media` (participating media; docs/dataset.md; rendered here first where missing):
# gen22 its paired control. 16 were planned; cut to 8 in stop 55, before any training, because a
# `media` sequence took 2-22 minutes to render two at once and 16 would not fit one session; and
# their inputs carry the volume normals of stop 55 (jnds_deploy.cycles; the first five re-rendered or resumed
# by scripts/reguide_volumes.py). Written in stop 54 with its rule (docs/training.md, "gen23"),
# before anything of it was trained or scored and before gen22 was scored.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen23.sh > runs/gen23.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
$J dataset --out data --split train --engine cycles --train-sequences 8 --glass-sequences 16 --print-sequences 16 \
    --media-sequences 8 --jobs 2
mkdir -p runs/gen23
# gen14, the init of gen16-gen23: the shipped checkpoint before stop 51
[ -f runs/gen23/gen14.pt ] || git show a60bb20:jnds_deploy/checkpoints/jnds.pt > runs/gen23/gen14.pt
$J train --data data --run runs/gen23 --init runs/gen23/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --fp32-steps 2000 --qat-steps 200 --lr 2e-4 \
    --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen23/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen22/checkpoint.pt \
    runs/gen23/checkpoint.pt --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen23/eval.json --sheet runs/gen23/eval.jpg
