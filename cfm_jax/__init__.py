"""cfm_jax: coupled forward and inverse models for learning robot controllers.

JAX + MuJoCo MJX implementation of Bechtle et al., "Leveraging Forward Model Prediction Error
for Learning Control" (ICRA 2021).
"""

from cfm_jax import _xla

FAST_XLA = _xla.configure()  # must run before any JAX computation; see cfm_jax/_xla.py

__version__ = "0.1.0"
