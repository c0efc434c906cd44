#!/usr/bin/env bash
# Stop 65: a fresh machine with no data/ and no runs/. What the next sessions on this machine run,
# in order, unattended, each step resuming where it stopped (background processes die with a
# session: start this again in the next). gen21's training set with cheap references (as
# scripts/chain62.sh rendered it), gen31's feature-loss network on it, the evaluation sets the
# rules score on (validation, the two holdouts), `gen33`'s scores for the record, `gen34` (its
# control), then `gen32` (docs/training.md, "`gen34`", "`gen32`"). Stop 65 trained `gen33` (issue 24's guide input, "`gen33`")
# after the feature net, before `gen32`, whose step-600 checkpoint went with the Zen 3's runs/;
# once `gen33`'s verdict was in (not shipped: `gen32` starts from `gen21`), its training step left
# this script and `gen32` joined it. Run it in its own session, niced:
#   (setsid nohup bash -c 'echo $$ > /tmp/chain65.sid; exec nice bash scripts/chain65.sh' >> runs/chain65.log 2>&1 &)
# Pause it with `pkill -STOP -s $(cat /tmp/chain65.sid)`, go on with -CONT.
set -ex
cd "$(dirname "$0")/.."
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
# gen33 was trained in stop 65 and not shipped (docs/training.md): scored for the record where its
# run is still here, not trained again where it is gone
[ ! -f runs/gen33/checkpoint.pt ] || bash scripts/gen33.sh
# gen33's control (docs/training.md, "`gen34`"), where gen33's run is here
[ ! -f runs/gen33/checkpoint.pt ] || bash scripts/gen34.sh
bash scripts/gen32.sh
