#!/usr/bin/env bash
# Stop 66: what follows scripts/chain65.sh, which it replaced at 22:43 in the middle of the holdout's
# render; it leaves out `gen33`'s record score (`gen34`'s own score has `gen33` too). Each
# step resumes where it stopped or is skipped when done (background processes die with a
# session: start this again in the next). chain65's data steps first (no-ops where rendered: a
# fresh machine renders them), then `gen34` and its score, `gen36` (`gen34` with a warm-up), then
# `gen35`'s training set (gen21's 132 sequences linked, 124 more seeds of the same kinds rendered
# beside them: docs/dataset.md, "Stop 66"), `gen35`, then `gen32` (docs/training.md, "`gen36`",
# "`gen35`", "`gen32`"). Don't edit it while it runs (bash reads it as it goes). Run it in its own
# session, niced:
#   (setsid nohup bash -c 'echo $$ > /tmp/chain66.sid; exec nice bash scripts/chain66.sh' >> runs/chain66.log 2>&1 &)
# Pause it with `pkill -STOP -s $(cat /tmp/chain66.sid)`, go on with -CONT.
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
# gen34 needs gen33's run (its init and the score's third checkpoint): where that is gone, so is
# the control gen35 and gen36 are read against
[ ! -f runs/gen33/checkpoint.pt ] || bash scripts/gen34.sh
# gen34 with a warm-up (docs/training.md, "`gen36`"): no new data needed, so before gen35's
[ ! -f runs/gen34/checkpoint.pt ] || bash scripts/gen36.sh
# gen35's 256 sequences: the 132 as links (data/spp8/train stays what gen31-gen34 and gen32 read),
# the new seeds rendered into data/spp8-256/train itself
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
bash scripts/gen32.sh
