#!/usr/bin/env bash
# Make .gpu/: what tools/gpu_train.sh needs on a lent GPU machine that cannot download
# anything (Python 3.12 there): Mitsuba + Dr.Jit cut down to the cuda_ad_rgb variant and
# the plugins our scenes load (the whole wheel is over the 64 MiB the device tool
# carries), and the OpenEXR and flip-evaluator wheels. Run here, where pip reaches PyPI.
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
dl() {
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$tmp" "$@"
}
dl mitsuba==3.9.1 drjit==1.5.0 openexr==3.5.3 flip-evaluator==1.7
mkdir -p "$tmp/x" .gpu
(cd "$tmp/x" && unzip -q "$tmp"/mitsuba-*.whl && unzip -q -o "$tmp"/drjit-*.whl)
m="$tmp/x/mitsuba"
rm -rf "$m"/llvm_* "$m"/scalar_* "$m"/cuda_ad_mono* "$m"/cuda_ad_spectral* "$m"/include "$m"/cmake \
  "$m"/mitsuba_stubs "$m"/pkgconfig "$m"/data/sunsky "$tmp"/x/drjit/include "$tmp"/x/drjit/cmake
# plugins: the ones jnds_deploy.render.scene names, the defaults Mitsuba adds (film,
# sampler, sensor, filters, spectra) and the shape plumbing load_dict uses
keep="area bitmap cube diffuse directional envmap rectangle sphere roughconductor roughplastic conductor
  plastic uniform srgb d65 regular irregular rawconstant constant independent stratified multijitter
  ldsampler hdrfilm perspective box gaussian tent mitchell catmullrom lanczos path direct depth merge
  instance shapegroup null twosided mask obj ply serialized spot point distant"
mkdir "$tmp/plugins"
for p in $keep; do mv "$m/plugins/$p.so" "$tmp/plugins/"; done
rm -rf "$m/plugins" && mv "$tmp/plugins" "$m/plugins"
tar cJf .gpu/mi.tar.xz -C "$tmp/x" mitsuba drjit
cp "$tmp"/openexr-*.whl "$tmp"/flip_evaluator-*.whl .gpu/
grep -qx "/.gpu/" .git/info/exclude 2>/dev/null || { mkdir -p .git/info; echo "/.gpu/" >> .git/info/exclude; }
du -sh .gpu
