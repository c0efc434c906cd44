#!/usr/bin/env bash
# The gen35 run from wherever it stopped, unattended; every step resumes or is skipped when
# done. Twice the training sequences: `gen34`'s command on data/spp8-256/train (gen21's 132 and
# 124 more seeds of the same kinds, docs/dataset.md, "Stop 66"), seed 35, the same init
# (`gen33`'s frozen runs/gen33/init.pt, the shipped `gen21`), steps and feature-loss network;
# with `gen33`'s guide flags where `gen34`'s rule, applied to its score below, finds that the
# guide helps. Its control is the run it copies (`gen34`, or `gen33` with the guide). Written in
# stop 66 with its rules (docs/training.md, "`gen35`"), before any of it was rendered, trained
# or scored. Needs scripts/chain66.sh's data and `gen34`'s score. Run it in its own session,
# niced, e.g.
#   setsid nohup nice bash scripts/gen35.sh > runs/gen35.log 2>&1 &
set -ex
cd "$(dirname "$0")/.."
J=.venv/bin/jnds
PY=.venv/bin/python
[ -f runs/gen33/init.pt ] && [ -f runs/gen34/eval.json ]
# gen34's rule (docs/training.md, "`gen34`"): the guide helps if gen33 is ahead of gen34 on the
# 12 holdout sequences by >= 0.05 dB of mean PSNR and in mean FLIP, losing <= 0.05 dB to it on
# validation
helps=$($PY - <<'EOF'
import json
r = json.load(open("runs/gen34/eval.json"))
def holdouts(method, metric):
    seqs = [s for split in ("holdout", "holdout2") for s in r[split][method]["sequences"].values()]
    assert len(seqs) == 12, len(seqs)
    return sum(s[metric] for s in seqs) / len(seqs)
val = {m: r["val"][m]["mean"]["psnr"] for m in ("gen33", "gen34")}
print(int(holdouts("gen33", "psnr") - holdouts("gen34", "psnr") >= 0.05
          and holdouts("gen33", "flip") < holdouts("gen34", "flip") and val["gen34"] - val["gen33"] <= 0.05))
EOF
)
if [ "$helps" = 1 ]; then guide="--guide-albedo --guide-init split"; control=gen33; else guide=; control=gen34; fi
mkdir -p runs/gen35/data/train
for d in data/spp8-256/train/*/; do
    ln -sfn "$(readlink -f "$d")" "runs/gen35/data/train/$(basename "$d")"
done
ln -sfn "$PWD/data/val" runs/gen35/data/val
[ "$(ls runs/gen35/data/train | wc -l)" = 256 ]
[ -f runs/feature-spp8/feature_net.pt ]
$J train --data runs/gen35/data --run runs/gen35 --init runs/gen33/init.pt --preset large --output-width 24 \
    --fixed-upsample --cross-cuts --upsample-root 4 --patch 80 --unroll 8 --firefly-clamp 16 --diffuse-fill \
    --albedo-at-holes $guide --clean-references oidn --fp32-steps 2000 --qat-steps 200 \
    --lr 1e-4 --qat-lr 2e-5 --spatial-loss l1+feature --feature-net runs/feature-spp8/feature_net.pt --lowfreq-loss 2.0 \
    --val-every 100000 --threads 2 --seed 35 --exposure -4 8 --rotate-normals --flips --balance-renderers
[ "${1:-}" = train ] && exit 0
# the three in one run: the init, the control, gen35
[ -f runs/gen35/eval.json ] || $J evaluate --checkpoint runs/gen33/init.pt runs/$control/checkpoint.pt \
    runs/gen35/checkpoint.pt --data data/holdout data/holdout2 data/val --baselines --threads 2 \
    --out runs/gen35/eval.json --sheet runs/gen35/eval.jpg
