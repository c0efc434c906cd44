#!/usr/bin/env bash
# The gen24 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen23's recipe, seed, init and training set (scripts/gen23.sh: gen14 fine-tuned 2200
# steps on 172 sequences, 8 of them `media`) with the diffuse holes filled
# (--diffuse-fill, model.ModelConfig.diffuse_fill, stop 56): gen23 its paired control.
# Written in stop 56 with its rule (docs/training.md, "gen24"), before anything of it was
# trained or scored. Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen24.sh > runs/gen24.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen24
# gen14, the init of gen16-gen24: the shipped checkpoint before stop 51
[ -f runs/gen24/gen14.pt ] || git show a60bb20:jnds_deploy/checkpoints/jnds.pt > runs/gen24/gen14.pt
$J train --data data --run runs/gen24 --init runs/gen24/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill --fp32-steps 2000 --qat-steps 200 \
    --lr 2e-4 --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen24/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen23/checkpoint.pt \
    runs/gen24/checkpoint.pt --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen24/eval.json --sheet runs/gen24/eval.jpg
