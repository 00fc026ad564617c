#!/usr/bin/env bash
# The GPU check (experiments/gpu_check.py says what it runs and prints), on a machine with a
# GPU and the JAX it has. First, where pip reaches a package index:
#   python experiments/gpu_check.py prepare      # wheels the GPU machine lacks -> .whl/
# then, on the GPU machine, from the repository root (with .whl/ brought along):
#   bash experiments/gpu_check.sh [--budget 450] [...]   # fits in 8 minutes
# The wheels: experiments/device_env.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE_SITE="${GPU_CHECK_SITE:-/tmp/cfm_jax_gpu_check_site}"
# shellcheck source=experiments/device_env.sh
source experiments/device_env.sh
exec "$PY" experiments/gpu_check.py run "$@"
