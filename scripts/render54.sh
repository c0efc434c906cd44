#!/usr/bin/env bash
# Stop 54: 16 sequences of the Cycles training kind `media` (seeds 16000-16015; docs/dataset.md),
# resumable (re-run it: finished sequences are skipped, a started one resumes from its frames).
# Run it in its own session at the lowest priority beside a training run, e.g.
#   setsid nohup bash -c 'echo 19 > /proc/$$/autogroup; exec bash scripts/render54.sh' > runs/render54.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
.venv/bin/jnds dataset --out data --split train --engine cycles --train-sequences 8 --media-sequences 16 --jobs 1
