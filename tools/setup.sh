#!/usr/bin/env bash
# Set up a fresh machine: Debian's libllvm19 (Mitsuba's LLVM backend), then .venv with the
# package and the extras named in $EXTRAS, then .venv-blender with Blender (bpy). Safe to re-run.
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS="${EXTRAS:-train,render,dev}"

# apt_install FILE PACKAGE WHY: install the Debian package if FILE is missing (root + apt only)
apt_install() {
  [ -e "$1" ] && return 0
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "setup: installing $2 ($3)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "$2" >/dev/null
  else
    echo "setup: warning: $1 missing and apt-get unavailable: $3 will not work as intended" >&2
  fi
}

apt_install /usr/lib/x86_64-linux-gnu/libLLVM-19.so libllvm19 \
  "Mitsuba's llvm_ad_rgb backend; without it the renderer falls back to slow scalar_rgb"
# numba's thread-safe threading layer: the server runs frames of several streams at once,
# and numba's default layer aborts on concurrent parallel calls
apt_install /usr/lib/x86_64-linux-gnu/libgomp.so.1 libgomp1 "numba's thread-safe threading layer (GNU OpenMP)"

if [ ! -x .venv/bin/python ]; then
  "${PYTHON:-python3}" -m venv .venv
fi
# torch==2.13.0 resolves to the CPU wheel this machine keeps on disk (pip's find-links)
.venv/bin/pip install -q -e ".[${EXTRAS}]" 2>&1 | grep -v "^WARNING: Location" || true
.venv/bin/python -c "import jnds_deploy, onnxruntime, OpenEXR, cv2; print('setup: ok')"

# Blender as a Python module, for `jnds render --engine cycles` and the Blender tests: its
# own environment, as bpy pins numpy < 2 (BLENDER=0 skips it)
if [ "${BLENDER:-1}" != 0 ]; then
  if [ ! -x .venv-blender/bin/python ]; then
    "${PYTHON:-python3}" -m venv .venv-blender
  fi
  .venv-blender/bin/pip install -q bpy==5.0.1 2>&1 | grep -v "^WARNING: Location" || true
  # the package itself, editable and without its dependencies (Blender's numpy stays): what
  # Blender's Python imports of it (jnds_deploy.blender) needs numpy and OpenEXR alone
  .venv-blender/bin/pip install -q --no-deps -e . 2>&1 | grep -v "^WARNING: Location" || true
  .venv-blender/bin/python -c "import bpy, jnds_deploy.blender; print('setup: ok, Blender', bpy.app.version_string)"
fi
