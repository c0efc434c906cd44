#!/bin/bash
# Fine-tune the shipped checkpoint with L1 and with the feature loss, same budget and seed.
set -e
cd "$(dirname "$0")/.."
source .venv/bin/activate
common="--data data --init jnds_deploy/checkpoints/jnds-small.pt --fp32-steps 400 --lr 3e-4 --qat-steps 150 --val-every 550 --quiet"
/usr/bin/time -f "%e s" jnds train --run runs/ft-l1 --spatial-loss l1 $common
/usr/bin/time -f "%e s" jnds train --run runs/ft-feature --spatial-loss feature --feature-net runs/feature/feature_net.pt $common
