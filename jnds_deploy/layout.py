"""The network's input channels, in order: shared by the model (torch) and the runtime
(numpy, no torch), so that deploying the ONNX pipeline does not need torch."""

# channels of the current inputs and of the history, in order
CURRENT = (("diffuse", 3), ("specular", 3), ("albedo", 3), ("normal", 3), ("roughness", 1))
HISTORY = (("diffuse", 3), ("specular", 3), ("albedo", 3), ("normal", 3))
N_CURRENT = sum(c for _, c in CURRENT)
N_HISTORY = sum(c for _, c in HISTORY)

# geometric history rejection (jnds_deploy.filters.disoccluded): a history normal further
# than acos(REJECT_COS) ~ 46 deg from every current normal in the 3x3 neighbourhood is
# another surface; a normal with |x| + |y| + |z| below BACKGROUND is background (unit: >= 1)
REJECT_COS = 0.7
BACKGROUND = 0.5

# the upsample filter's root interpolation (jnds_deploy.filters.upsample_filter) raises the
# composite to this floor first: the derivative of x^(1/root) is infinite at 0
ROOT_FLOOR = 1e-10
