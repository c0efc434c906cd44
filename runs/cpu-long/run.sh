#!/bin/bash
# Two CPU fine-tunes of the checkpoint shipped on 2026-11-23 (runs/cpu-root4), one after
# the other, each alone on both cores, with fourth-root upsampling and the same number of
# patch pixels x frames:
#   runs/cpu-long-u6   64x64 native patches (as before), FP32_STEPS + QAT_STEPS
#   runs/cpu-long-p96  96x96 native patches (validation frames are 192x108), 1/2.25 the steps
# Resumable: run it again with the same arguments.
# Usage: bash runs/cpu-long/run.sh FP32_STEPS QAT_STEPS (of the 64x64 run)
set -e
cd "$(dirname "$0")/../.."
source .venv/bin/activate
common="--data data --init runs/cpu-root4/checkpoint.pt --upsample-root 4 --lr 1.5e-4 --qat-lr 4e-5
  --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --val-every 100000
  --threads 2 --seed 1 --quiet --unroll 6"
/usr/bin/time -f "%e s" jnds train --run runs/cpu-long-u6 --patch 64 --fp32-steps "$1" --qat-steps "$2" $common
/usr/bin/time -f "%e s" jnds train --run runs/cpu-long-p96 --patch 96 --fp32-steps $(($1 * 4 / 9)) \
  --qat-steps $(($2 * 4 / 9)) $common
