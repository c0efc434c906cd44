"""jnds_deploy: the network of Thomas et al. 2022 (temporally stable real-time joint neural
denoising and supersampling), deployed as an int8 ONNX pipeline.

Importing the package changes nothing in the process, nor does building a pipeline unless
asked; every process-wide setting is opt-in and in ``jnds_deploy.process``."""

__version__ = "0.1.0"
