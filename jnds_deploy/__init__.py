"""jnds_deploy: the network of Thomas et al. 2022 (temporally stable real-time joint neural
denoising and supersampling), deployed as an int8 ONNX pipeline."""
__version__ = "0.1.0"
