"""Training the network on rendered sequences: ``jnds train``, ``jnds train-feature-net``
and ``jnds evaluate``.

- ``config``: ``TrainConfig``, what a run is (written as ``<run>/config.json``);
- ``data``: sequences in memory and the patch sampler;
- ``losses``: the losses of Sec. 3.3 (``feature_loss``: the network of Eq. 6);
- ``train``: the loop, fp32 then QAT, resumable;
- ``evaluate``: the model and the baselines scored on sequences.

Only this package imports torch's training machinery; the runtime needs none of it.
"""
