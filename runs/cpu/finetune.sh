#!/bin/bash
# Two CPU fine-tunes of the shipped checkpoint side by side (one thread each, same data,
# seed, steps and learning rates), both with the geometric history rejection in the loop
# (JNDS.forward applies it since 2026-11-23):
#   runs/cpu-reject  the paper's linear upsampling
#   runs/cpu-root4   the upsample filter interpolating 4th roots (--upsample-root 4)
# Usage: bash runs/cpu/finetune.sh FP32_STEPS QAT_STEPS
set -e
cd "$(dirname "$0")/../.."
source .venv/bin/activate
common="--data data --init jnds_deploy/checkpoints/jnds-small.pt --fp32-steps $1 --qat-steps $2 --lr 2e-4
  --qat-lr 5e-5 --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --val-every 100000
  --threads 1 --quiet"
/usr/bin/time -f "%e s" jnds train --run runs/cpu-reject $common > runs/cpu/reject.log 2>&1 &
/usr/bin/time -f "%e s" jnds train --run runs/cpu-root4 --upsample-root 4 $common > runs/cpu/root4.log 2>&1 &
wait
