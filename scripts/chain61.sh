#!/usr/bin/env bash
# Stop 61: what the next sessions on this machine run, in order, unattended, each step resuming
# where it stopped (a session's background processes die with it: start this again in the next):
# the data with references (scripts/render59.sh), then `gen30` (the guide albedo, issue 24), then
# `gen27` (the 16-channel output block, issue 25), one after the other so that each training run
# has the two cores alone (docs/dataset.md: a render beside a training run slows it many times).
# Their rules are in docs/training.md, written before they ran. Run it in its own session, niced:
#   setsid nohup nice bash scripts/chain61.sh >> runs/chain61.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
bash scripts/render59.sh
bash scripts/gen30.sh
bash scripts/gen27.sh
