#!/usr/bin/env bash
# Stop 67: what follows scripts/chain66.sh, which it replaced while `gen35` trained: chain66's
# steps (each resumes where it stopped, or is skipped when done), with `gen37` (docs/training.md,
# "`gen37`") between `gen35` and `gen32`. It first waits for a chain66 or a `gen35` still running
# (the swap leaves `gen35` running on its own). Background processes die with a session: start
# this again in the next. Don't edit it while it runs (bash reads it as it goes). Run it in its
# own session, niced:
#   (setsid nohup bash -c 'echo $$ > /tmp/chain67.sid; exec nice bash scripts/chain67.sh' >> runs/chain67.log 2>&1 &)
# Pause it with `pkill -STOP -s $(cat /tmp/chain67.sid)`, go on with -CONT.
set -ex
cd "$(dirname "$0")/.."
while pgrep -f "scripts/(chain66|gen35)\.sh" > /dev/null; do sleep 30; done
J=.venv/bin/jnds
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}
$J dataset --out data/spp8 --split train --reference-spp 8 --train-sequences 24 --moving-sequences 8 --jobs 2
$J dataset --out data/spp8 --split train --reference-spp 8 --engine cycles --train-sequences 8 \
    --mixed-sequences 24 --lights-sequences 24 --interior-sequences 12 --detail-sequences 16 \
    --layers-sequences 16 --jobs 2
[ -f runs/feature-spp8/feature_net.pt ] || $J train-feature-net --data data/spp8 --clean-references oidn \
    --out runs/feature-spp8/feature_net.pt --quiet
for e in mitsuba cycles; do $J dataset --out data --split val --engine $e --jobs 2; done
$J dataset --out data --split holdout --engine cycles --jobs 2
$J dataset --out data --split holdout2 --engine cycles --jobs 2
# each run is skipped once scored (a finished run's `jnds train` still loads its data first)
[ ! -f runs/gen33/checkpoint.pt ] || [ -f runs/gen34/eval.json ] || bash scripts/gen34.sh
[ ! -f runs/gen34/checkpoint.pt ] || [ -f runs/gen36/eval.json ] || bash scripts/gen36.sh
if [ ! -f runs/gen35/eval.json ]; then
    mkdir -p data/spp8-256/train
    for d in data/spp8/train/*/; do
        ln -sfn "$PWD/$d" "data/spp8-256/train/$(basename "$d")"
    done
    $J dataset --out data/spp8-256 --split train --reference-spp 8 --train-sequences 48 --moving-sequences 16 --jobs 2
    $J dataset --out data/spp8-256 --split train --reference-spp 8 --engine cycles --train-sequences 8 \
        --mixed-sequences 48 --lights-sequences 48 --interior-sequences 24 --detail-sequences 32 \
        --layers-sequences 32 --jobs 2
    [ "$(ls data/spp8-256/train | wc -l)" = 256 ]
    bash scripts/gen35.sh
fi
[ ! -f runs/gen34/checkpoint.pt ] || [ -f runs/gen37/eval.json ] || bash scripts/gen37.sh
bash scripts/gen32.sh
