"""``jnds export``: split the model at the paper's boundaries into ONNX graphs.

- ``network.onnx``: input block + feature extractor + output block at native resolution.
  Inputs ``current`` (N, 13, H, W) and ``history`` (N, 12, H, W), linear as stored (the
  tonemap of Eq. 1 is inside), and ``guide`` (N, 3, H, W), the guide albedo, for a model
  trained with it (``ModelConfig.guide_albedo``). Outputs: every per-pixel kernel and blend weight of the
  filter paths (already clamped / normalized / squashed) and the upsample features.
- ``upsample.onnx``: the upsample block's kernel prediction for the target resolution,
  computed by native-resolution convolutions (sub-pixel form, ``model.SubPixelUpsampleBlock``).
  Inputs ``composite`` (N, 3, H, W) linear and ``features`` (N, F, H, W); output
  ``kernel`` (N, s*s*9, H, W) in phase layout (``filters.to_phases`` of the (N, 9, sH, sW)
  kernel).

Warping, the filter paths, the composite and kernel application are not in ONNX: they
are the runtime's numpy/opencv stage. Spatial sizes are dynamic; H and W must be
multiples of ``pad_multiple`` (the runtime pads). ``manifest.json`` (``artifacts.Manifest``)
says everything a runtime needs; every export ends with a validation of ONNX Runtime
against PyTorch.
- ``network.no-<groups>.onnx``: pruned variants without the diffuse or specular path's
  kernels or the upsample features (``prune``), for adaptive execution.

``convert`` (torch) is imported on first use, so the runtime can read ``prune`` without torch.
"""

__all__ = ["ExportConfig", "export"]


def __getattr__(name):
    if name in __all__:
        from . import convert

        return getattr(convert, name)
    raise AttributeError(name)
