#!/usr/bin/env bash
# The gen25 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. gen22's recipe, seed, init and training set (scripts/gen22.sh: gen14 fine-tuned 2200
# steps on the 164 sequences of data/train that are not `media`, linked into runs/gen25/data)
# with the diffuse holes filled (--diffuse-fill, stop 56): gen22 its paired control, the
# shipped model (gen21 with the fill) the one to beat. Written in stop 56 with its rule
# (docs/training.md, "gen25"), before anything of it was trained or scored, after gen24.
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/gen25.sh > runs/gen25.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
mkdir -p runs/gen25/data/train
for d in data/train/*/; do
    case "$(basename "$d")" in cycles-media-*) continue ;; esac
    ln -sfn "$PWD/$d" "runs/gen25/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen25/data/val
[ "$(ls runs/gen25/data/train | wc -l)" = 164 ]
[ -f runs/gen25/gen14.pt ] || git show a60bb20:jnds_deploy/checkpoints/jnds.pt > runs/gen25/gen14.pt
$J train --data runs/gen25/data --run runs/gen25 --init runs/gen25/gen14.pt --preset large --fixed-upsample \
    --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill --fp32-steps 2000 \
    --qat-steps 200 --lr 2e-4 --qat-lr 4e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt \
    --lowfreq-loss 2.0 --val-every 100000 --threads 2 --seed 20 --exposure -4 8 --rotate-normals --flips \
    --balance-renderers
[ -f runs/gen25/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen22/checkpoint.pt \
    runs/gen25/checkpoint.pt --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen25/eval.json --sheet runs/gen25/eval.jpg
