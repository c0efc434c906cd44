"""jnds_deploy: the network of Thomas et al. 2022 (temporally stable real-time joint neural
denoising and supersampling), deployed as an int8 ONNX pipeline."""
__version__ = "0.1.0"

import os as _os

# numba's default "workqueue" threading layer aborts the process when two threads run
# parallel loops at once (the server does); "threadsafe" picks TBB or GNU OpenMP
_os.environ.setdefault("NUMBA_THREADING_LAYER", "threadsafe")
# numba leaves LLVM's SLP vectorizer off by default; the warp loop
# (runtime.filters._warp_rows) relies on it to turn its 12 per-channel sums into vector
# FMAs (39 against 67 ms at 1280x720). It changes no result: without fast-math flags it
# reorders no sum
_os.environ.setdefault("NUMBA_SLP_VECTORIZE", "1")
