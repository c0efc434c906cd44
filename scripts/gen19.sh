#!/usr/bin/env bash
# The gen19 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen18's recipe, data and seed (scripts/gen18.sh) with the low-frequency loss term at
# weight 2.0: the next point of the dose-response that gen16 (0), gen17 (0.5) and gen18 (1.0)
# made monotonic on both holdouts (docs/training.md, "gen18 and soups"). Started in stop 52 and
# chosen there over the shipped gen18 (`jnds` in the evaluation) by the rule written before it
# was scored (ahead on both holdouts together in mean PSNR and mean FLIP, validation down at
# most 0.05 dB); shipped.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen19.sh > runs/gen19.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen19
# gen14, the init of gen16-gen18: the shipped checkpoint before stop 51
[ -f runs/gen19/gen14.pt ] || git show a60bb20:jnds_deploy/checkpoints/jnds.pt > runs/gen19/gen14.pt
$J train --data data --run runs/gen19 --init runs/gen19/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --fp32-steps 2000 --qat-steps 200 --lr 2e-4 \
    --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ -f runs/gen19/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen19/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 --out runs/gen19/eval.json \
    --sheet runs/gen19/eval.jpg
