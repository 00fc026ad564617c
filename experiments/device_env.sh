# Sourced by the device scripts (gpu_check.sh, robot_zoo_gpu.sh), from the repository root:
# installs the wheels of `python experiments/gpu_check.py prepare` (.whl/) into a folder of
# their own and puts it on PYTHONPATH, beside (never over) the machine's JAX, flax, optax and
# orbax: --no-deps, so pip changes nothing that is installed. PY is the Python to use
# (default python3), DEVICE_SITE the folder (default /tmp/cfm_jax_device_site). Without
# .whl/ the packages installed are used.
PY="${PY:-${PYTHON:-python3}}"
DEVICE_SITE="${DEVICE_SITE:-/tmp/cfm_jax_device_site}"
if compgen -G ".whl/*.whl" >/dev/null; then
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$DEVICE_SITE" .whl/*.whl || return 1
  export PYTHONPATH="$DEVICE_SITE${PYTHONPATH:+:$PYTHONPATH}"
else
  echo "device_env: no .whl/ folder: using the packages installed (run 'python experiments/gpu_check.py prepare' first if any is missing)" >&2
fi
