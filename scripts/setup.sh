#!/usr/bin/env bash
# Set up a fresh machine: Debian's libllvm19 (Mitsuba's LLVM backend), then .venv with the
# package and the extras named in $EXTRAS. Safe to re-run.
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS="${EXTRAS:-render,dev}"

if [ ! -e /usr/lib/x86_64-linux-gnu/libLLVM-19.so ]; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "setup: installing libllvm19 (Mitsuba's llvm_ad_rgb backend)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libllvm19 >/dev/null
  else
    echo "setup: warning: libLLVM-19 missing and apt-get unavailable; Mitsuba falls back to scalar_rgb (slow)" >&2
  fi
fi

# GNU OpenMP: numba's thread-safe threading layer (the server runs frames of several
# streams at once; numba's default layer aborts on concurrent parallel calls)
if [ ! -e /usr/lib/x86_64-linux-gnu/libgomp.so.1 ]; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "setup: installing libgomp1 (numba's thread-safe threading layer)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libgomp1 >/dev/null
  else
    echo "setup: warning: libgomp.so.1 missing and apt-get unavailable; numba's parallel loops will fail" >&2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  "${PYTHON:-python3}" -m venv .venv
fi
# torch==2.13.0 resolves to the CPU wheel this machine keeps on disk (pip's find-links)
.venv/bin/pip install -q -e ".[${EXTRAS}]" 2>&1 | grep -v "^WARNING: Location" || true
.venv/bin/python -c "import jnds_deploy, torch, onnxruntime, OpenEXR, cv2; print('setup: ok, torch', torch.__version__)"
