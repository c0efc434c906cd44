#!/usr/bin/env bash
# Stop 52's candidates against the shipped gen17 on the selection set (holdout and holdout2
# together) and validation, after scripts/gen18.sh: gen18 and two weight averages
# (experiments/soup.py). The rule was written before scoring (docs/training.md, "gen18 and
# soups"). Resumable: each step is skipped when its output exists.
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
P=.venv/bin/python
mkdir -p runs/soup
$P -c "import sys; from jnds_deploy.checkpoint import read_checkpoint; \
    sys.exit(read_checkpoint('runs/gen18/checkpoint.pt')['state']['phase'] != 'done')"  # gen18 finished
[ -f runs/soup/wise-14-17.pt ] || $P experiments/soup.py --checkpoint runs/gen17/gen14.pt runs/gen17/checkpoint.pt \
    --out runs/soup/wise-14-17.pt
[ -f runs/soup/soup-16-17-18.pt ] || $P experiments/soup.py --checkpoint runs/gen16/checkpoint.pt \
    runs/gen17/checkpoint.pt runs/gen18/checkpoint.pt --out runs/soup/soup-16-17-18.pt
[ -f runs/soup/eval.json ] || $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt runs/gen18/checkpoint.pt \
    runs/soup/soup-16-17-18.pt runs/soup/wise-14-17.pt --data data/holdout data/holdout2 data/val --baselines \
    --threads 2 --out runs/soup/eval.json --sheet runs/soup/eval.jpg
