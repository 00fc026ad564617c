#!/usr/bin/env bash
# The GPU check (experiments/gpu_check.py says what it runs and prints), on a machine with a
# GPU and the JAX it has. First, where pip reaches a package index:
#   python experiments/gpu_check.py prepare      # wheels the GPU machine lacks -> .whl/
# then, on the GPU machine, from the repository root (with .whl/ brought along):
#   bash experiments/gpu_check.sh [--budget 450] [...]   # fits in 8 minutes
# The wheels go to a folder of their own on PYTHONPATH, beside (never over) the machine's
# JAX, flax, optax and orbax: --no-deps, so pip changes nothing that is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-python3}"
SITE="${GPU_CHECK_SITE:-/tmp/cfm_jax_gpu_check_site}"
if compgen -G ".whl/*.whl" >/dev/null; then
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$SITE" .whl/*.whl
  export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}"
else
  echo "gpu_check: no .whl/ folder: using the packages installed (run 'prepare' first if any is missing)" >&2
fi
exec "$PY" experiments/gpu_check.py run "$@"
