"""jnds_deploy: the network of Thomas et al. 2022 (temporally stable real-time joint neural
denoising and supersampling), deployed as an int8 ONNX pipeline."""
__version__ = "0.1.0"

import os as _os

# numba's default "workqueue" threading layer aborts the process when two threads run
# parallel loops at once (the server does); "threadsafe" picks TBB or GNU OpenMP
_os.environ.setdefault("NUMBA_THREADING_LAYER", "threadsafe")
