#!/usr/bin/env bash
# The 16 training sequences of the Cycles `layers` kind (seeds 13000-13015; docs/dataset.md,
# "A ninth kind, layers"), rendered where missing: gen21's added data (scripts/gen21.sh).
# Run it in its own session, niced, e.g.
#   setsid nohup nice bash scripts/render53.sh > runs/render53.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
.venv/bin/jnds dataset --out data --split train --engine cycles --train-sequences 8 --layers-sequences 16 --jobs 2
