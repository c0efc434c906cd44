"""jnds_deploy: the network of Thomas et al. 2022 (temporally stable real-time joint neural
denoising and supersampling), deployed as an int8 ONNX pipeline.

Importing the package changes nothing in the process; process-wide tuning is opt-in
(``runtime.tune_numba``, ``runtime.PipelineConfig.keep_freed_memory``)."""
__version__ = "0.1.0"
