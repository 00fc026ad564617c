"""The impure shell around :mod:`cfm_jax.learning`: the loop (:func:`training.train`),
its files and checkpoints, and sweeps of many configs."""
