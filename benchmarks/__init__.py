"""The benchmarks: run each from the repository root as a module, e.g. ``python -m benchmarks.timing``
(``benchmarks/common.py`` says what they share)."""
