"""The impure shell around :mod:`cfm_jax.learning`: :func:`training.train` (a run's
records, files and checkpoints, its progress) and sweeps of many configs."""
