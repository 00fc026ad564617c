#!/usr/bin/env bash
# The development set (tests/robots) on one GPU machine, one process per arm at once: what
# ran issue 41's coupled-vs-inertia comparison on an H100 (2026-11-27; docs/benchmarks_gpu.md).
# On the device machine, from the repository root, with the wheels of
# `python experiments/gpu_check.py prepare` in .whl/:
#   ARMS="arx_l5 piper" TAG=coupled CAP=470 bash experiments/robot_zoo_gpu.sh
# TAG names experiments/zoo_flags/TAG.json (the flags added per arm); QS=1 also runs the
# quickstart with 5 seeds under each scale; NOTEST=1 skips the device tests beside it;
# NO_INSTALL=1 PY=python uses the packages installed (a check on a CPU machine).
# Results: $ZOO/seeds3_TAG/ARM/ (robot_zoo.py's folders), a tarball of them without
# checkpoints in $OUT.
set -u
cd "$(dirname "$0")/.."
PY=${PY:-python3}
if [ -z "${NO_INSTALL:-}" ]; then
  # shellcheck source=experiments/device_env.sh
  source experiments/device_env.sh || exit 1
fi
export XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
ZOO=${ZOO:-/tmp/zoo}; mkdir -p "$ZOO"
CAP=${CAP:-470}
nvidia-smi -L 2>/dev/null
$PY -c "import jax, mujoco; print('jax', jax.__version__, 'mujoco', mujoco.__version__, jax.devices())"
start=$(date +%s)
for r in ${ARMS:-m1013 piper lite6_continuous}; do
  timeout "$CAP" $PY experiments/robot_zoo.py --robots tests/robots --seeds 3 --out "$ZOO" \
    --tag ${TAG:-coupled} --flags-file experiments/zoo_flags/${TAG:-coupled}.json --table "$ZOO/table_$r.md" --only "$r" \
    > "$OUT/log_$r.txt" 2>&1 &
done
[ -z "${NOTEST:-}" ] && timeout 300 $PY -m pytest -q -p no:cacheprovider -p no:benchmark -n 4 tests/test_coupled_scale.py \
  tests/test_jax_private.py tests/test_native.py tests/test_update.py > "$OUT/tests.txt" 2>&1 &
if [ -n "${QS:-}" ]; then
  for sc in coupled inertia; do
    timeout "$CAP" $PY -m cfm_jax.cli train --seeds 5 --loop.torque-scale $sc --out /tmp/qs_$sc --quiet > "$OUT/qs_$sc.txt" 2>&1 &
  done
fi
wait
(cd /tmp && tar czf "$OUT/qs.tgz" --exclude=checkpoints --exclude=dataset.npz qs_* 2>/dev/null)
tail -3 "$OUT/tests.txt"
pkill -f "cfm_jax.cli train" ; sleep 3
echo "wall $(( $(date +%s) - start )) s"
(cd "$ZOO" && tar czf "$OUT/zoo.tgz" --exclude=checkpoints --exclude=dataset.npz .)
for f in "$ZOO"/seeds3_${TAG:-coupled}/*/metrics.csv "$ZOO"/seeds3_${TAG:-coupled}/*/*/metrics.csv; do
  [ -f "$f" ] && echo "$f $(tail -n +2 "$f" | wc -l) rows"
done
cat "$ZOO"/seeds3_${TAG:-coupled}/*/summary.md 2>/dev/null | head -80
