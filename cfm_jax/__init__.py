"""cfm_jax: coupled forward and inverse models for learning robot controllers.

JAX + MuJoCo implementation of Bechtle et al., "Leveraging Forward Model Prediction Error
for Learning Control" (ICRA 2021). Importing it sets the XLA flags (:mod:`cfm_jax._xla`),
turns on JAX's persistent compilation cache (``~/.cache/cfm_jax/jax``;
``CFM_JAX_COMPILATION_CACHE=0`` turns it off) and registers the tasks' defaults;
``__all__``'s names are imported on first use.

Examples:
  >>> import cfm_jax
  >>> result = cfm_jax.train(cfm_jax.Config(robot="iiwa14"))  # doctest: +SKIP
"""

from cfm_jax import _xla

FAST_XLA = _xla.configure()  # must run before any JAX computation; see cfm_jax/_xla.py
# JAX's persistent compilation cache (CFM_JAX_COMPILATION_CACHE=0: off); JAX decides at its
# first compilation whether a cache is used, so it is set here, before any.
COMPILATION_CACHE = _xla.use_compilation_cache()

# The tasks register their names and defaults (cfm_jax.config.TASK_DEFAULTS), which every
# config of them takes, and the forward-model kinds their options (FORWARD_OPTIONS): done
# here, so that a config made after `import cfm_jax` or any `from cfm_jax... import` is the
# task's experiment with its kind's options.
from cfm_jax import tasks as _tasks  # noqa: E402, F401
from cfm_jax.learning import forward_models as _forward_models  # noqa: E402, F401

__version__ = "0.1.0"

_LAZY = {
    "train": "cfm_jax.runs.training",
    "TrainResult": "cfm_jax.runs.training",
    "Experiment": "cfm_jax.learning.algorithm",
    "METRIC_COLUMNS": "cfm_jax.learning.algorithm",
    "Config": "cfm_jax.config",
    "TaskConfig": "cfm_jax.config",
    "ForwardModelConfig": "cfm_jax.config",
    "ControllerConfig": "cfm_jax.config",
    "LoopConfig": "cfm_jax.config",
    "ConfigError": "cfm_jax.config",
    "for_task": "cfm_jax.config",
    "sweep": "cfm_jax.runs.sweeps",
    "SweepResult": "cfm_jax.runs.sweeps",
    "SweepError": "cfm_jax.runs.sweeps",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cfm_jax' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_LAZY))
