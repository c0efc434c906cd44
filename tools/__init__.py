"""Tools of the repository (setup, shipping a model, training on a lent GPU machine); run the
Python ones from the repository root as modules, e.g. ``python -m tools.model_card``."""
