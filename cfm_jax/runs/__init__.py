"""The impure shell around :mod:`cfm_jax.learning`: :func:`training.train` runs Algorithm 1
in a loop, :mod:`.recorder` writes a run's files, :mod:`.checkpoint` saves and resumes it,
:mod:`.sweeps` runs many configs (locally or on Ray) and gathers their tables."""
