#!/usr/bin/env bash
# Ship a scored run: the mechanical half of shipping a model (as in commit af15bbe), in the
# order later steps need. The checkpoint and its model card first, then the graphs `make demo`
# makes, then every committed report that depends on the model. Each step leaves a stamp in
# RUN/ship/ and is skipped once stamped, so the script goes on where a session ended:
#   bash tools/ship.sh runs/NAME NAME zen5      # TAG names the timing and memory reports
# What it does not do: the model card's narrative (why this run, its rule and verdict), the
# README's headline figures and docs/model-gap.md; write those from the reports. Stop any
# training first: the timing and memory reports want the cores to themselves.
set -ex
cd "$(dirname "$0")/.."
RUN=${1:?run directory}; NAME=${2:?the run name}; TAG=${3:?CPU tag of the timing and memory reports, e.g. zen5}
PY=.venv/bin/python; J=.venv/bin/jnds; R=benchmarks/results; S=$RUN/ship
[ -f "$RUN/eval.json" ]    # scored by its rule first (its script's last step)
mkdir -p "$S"
step() { [ -f "$S/$1.done" ] && return 0; "${@:2}"; touch "$S/$1.done"; }

# the outgoing checkpoint, kept for the comparisons below (the lineage goes in docs/changelog.md)
step previous cp jnds_deploy/checkpoints/jnds.pt jnds_deploy/checkpoints/MODEL_CARD.md "$S/"
step checkpoint $PY -m tools.model_card --run "$RUN" --model "$NAME" --eval "$RUN/eval.json"
step export $J export --out out/artifacts
step calibrate $J calibrate --artifacts out/artifacts --data samples/orbit-160x90 --method qat
step model_eval $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt "$S/previous.pt" \
    --data data/val data/test data/holdout --baselines bicubic oidn-balanced --threads 2 \
    --out $R/model_eval.json --sheet $R/model_eval.jpg
step model_eval_holdout2 $J evaluate --checkpoint jnds_deploy/checkpoints/jnds.pt "$S/previous.pt" \
    --data data/holdout2 --baselines bicubic oidn-balanced --threads 2 \
    --out $R/model_eval_holdout2.json
step exposure_sweep $PY -m benchmarks.exposure_sweep --artifacts out/artifacts \
    --input data/val/cycles-darkroom-dolly-6001 data/val/procedural-orbit-2002 --out $R/exposure_sweep
step calibration $PY -m benchmarks.calibration --data data/val
step tradeoff $PY -m benchmarks.tradeoff --artifacts out/artifacts --data data/val
step card $PY -m tools.model_card --eval "$R/model_eval*.json"
step timing $PY -m benchmarks.timing --artifacts out/artifacts --out $R/timing-$TAG
step memory $PY -m benchmarks.memory --out $R/memory-$TAG --runs 5
