#!/usr/bin/env bash
# The gen20 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen19's recipe, data and seed (scripts/gen19.sh, weight 2.0) with colour
# augmentation (--colours: R, G, B permuted in half the samples, radiance tinted by up to half a
# stop per channel): gen19 is its control (the colour draws shift the random stream, so the
# batches are not exactly gen19's). The holdout2 street's chroma blobs are the
# failure it aims at. Started at the end of stop 52; chosen over the shipped gen19 (`jnds` in the
# evaluation) only by the rule written then (docs/training.md, "gen18 and soups").
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen20.sh > runs/gen20.log 2>&1 &
# and pause it (SIGSTOP to its session) during timings.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen20
# gen14, the init of gen16-gen20: the shipped checkpoint before stop 51
[ -f runs/gen20/gen14.pt ] || git show a60bb20:jnds_deploy/checkpoints/jnds.pt > runs/gen20/gen14.pt
$J train --data data --run runs/gen20 --init runs/gen20/gen14.pt --preset large --fixed-upsample --cross-cuts \
    --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --fp32-steps 2000 --qat-steps 200 --lr 2e-4 \
    --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips --colours --balance-renderers
[ -f runs/gen20/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen20/checkpoint.pt \
    --data data/holdout data/holdout2 data/val --baselines --threads 2 --out runs/gen20/eval.json \
    --sheet runs/gen20/eval.jpg
