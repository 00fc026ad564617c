"""Shared test setup.

``import cfm_jax`` must come before any JAX computation in the test process: it sets
``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` (see cfm_jax/_xla.py), without which MJX on
the iiwa compiles and runs about 1000x slower.
"""

import cfm_jax  # noqa: F401
