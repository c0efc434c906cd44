#!/bin/bash
# Continues runs/cpu-data48 in the QAT phase (its weights and learned ranges) on the same
# 48 training sequences, alone on both cores. Resumable: run it again.
# Usage: bash runs/cpu-data48-qat/run.sh QAT_STEPS
set -e
cd "$(dirname "$0")/../.."
source .venv/bin/activate
/usr/bin/time -f "%e s" jnds train --data data --run runs/cpu-data48-qat --patch 96 --fp32-steps 0 --qat-steps "$1" \
  --init runs/cpu-data48/checkpoint.pt --upsample-root 4 --lr 1.5e-4 --qat-lr 4e-5 \
  --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --val-every 100000 \
  --threads 2 --seed 3 --quiet --unroll 6
