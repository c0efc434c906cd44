#!/usr/bin/env bash
# The gen28 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. Issue 25's narrower output block without references: the shipped checkpoint cut to 16
# output-block channels (`--output-width 16`), its output block alone trained to reproduce
# the shipped model's outputs (`--teacher`, `--train-only network.output_block`; the input
# block and the U-Net stay the shipped ones), on the inputs of gen21's 132 training sequences
# rendered without references (`jnds dataset --no-reference`, minutes instead of the hours
# of the references). Written in stop 60 with its rule (docs/training.md, "gen28"), before
# anything of it was trained or scored. Run it in its own session, e.g.
#   setsid nohup bash scripts/gen28.sh > runs/gen28.log 2>&1 &
# and nothing else heavy beside it: PyTorch's threads slow down by tens of times when other
# processes hold the cores (stop 60: 105 s a step beside two Blender renders, 4.4 s alone).
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}
$J dataset --out data/distill --split train --engine cycles --train-sequences 8 --mixed-sequences 24 \
    --lights-sequences 24 --interior-sequences 12 --detail-sequences 16 --layers-sequences 16 --jobs 2 \
    --no-reference --quiet
$J dataset --out data/distill --split train --train-sequences 24 --moving-sequences 8 --jobs 2 --no-reference --quiet
[ "$(ls data/distill/train | wc -l)" = 132 ]
$J train --data data/distill --run runs/gen28 --init jnds_deploy/checkpoints/jnds.pt \
    --teacher jnds_deploy/checkpoints/jnds.pt --train-only network.output_block --preset large --output-width 16 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes --fp32-steps 0 --qat-steps 800 --qat-lr 1e-4 --lowfreq-loss 2.0 --val-every 100000 \
    --threads 2 --seed 28 --exposure -4 8 --rotate-normals --flips --balance-renderers --quiet
