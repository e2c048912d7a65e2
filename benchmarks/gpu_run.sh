#!/usr/bin/env bash
# One run on the GPU machine (the device tool): installs the carried packages, then runs the CUDA tests
# or one maintained benchmark; its log and the results it writes under docs/ land in $OUT.
#
#   bash benchmarks/gpu_run.sh tests [PYTEST ARGS]   the CUDA tests (no args: every test whose name asks
#                                                    for CUDA, the tiled kernels or a GPU)
#   bash benchmarks/gpu_run.sh NAME [ARGS]           python3 benchmarks/NAME.py ARGS (e.g. batch_hoi
#                                                    --device cuda; peers/newton_gpu --device cuda)
#   bash benchmarks/gpu_run.sh cli ARGS              physhand ARGS (e.g. cli bench solver --device cuda)
#   bash benchmarks/gpu_run.sh cache                 ~/.cache/warp back as $OUT/warp_cache.tar.xz
#
# The machine has no warp-lang or mujoco and cannot download them. Here, from the project root, pack them
# once: `bash ../shared/tools/device_bundle.sh` (ignored folders .dev1 .. .devN, one device call each).
# Then make the same call once per folder, back to back (a machine stays warm ~30 s after a call): with
# carry [".dev1"] .. [".devN-1"] it only stages that part; with [".devN"] (add ".devc" for a kernel
# cache) it installs into /tmp/site and runs. Later calls on the same warm machine carry nothing.
# A fresh machine compiles every Warp kernel first (the CUDA tests: 330 s on an H100, 15 s warm). A
# carried .devc/warp_cache.tar.xz is unpacked first, so only modules changed since compile: bring one
# back with `cache`, or build it for sm_90 on this CPU: `python benchmarks/aot_cache.py --merge
# .devc/warp_cache.tar.xz --out .devc/warp_cache.tar.xz`.
# GPU_RUN_LIMIT (s, default 560) stops the run in time for its files to come back from a 600 s call; at
# most 8 files come back, so beyond that $OUT's files are packed into one results_*.tgz.
set -uo pipefail
cd "$(dirname "$0")/.."
what=${1:?usage: gpu_run.sh tests [PYTEST ARGS] | NAME [ARGS] | cli ARGS | cache}; shift
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
py=${PYTHON:-python3}
export PYTHONPATH=/tmp/site:$PWD:$PWD/plugins${PYTHONPATH:+:$PYTHONPATH}
export MUJOCO_GL=${MUJOCO_GL:-disable} PYTHONUNBUFFERED=1

# set-up: stage the carried parts; the last folder's device_setup.sh joins them into /tmp/site (once)
ls .dev[0-9]*/bundle.part* >/dev/null 2>&1 && mkdir -p /tmp/stage && cp .dev[0-9]*/bundle.part* /tmp/stage/
if ! "$py" -c "import warp, mujoco" 2>/dev/null; then
  setup=$(ls .dev[0-9]*/device_setup.sh 2>/dev/null | tail -n 1)
  if [ -z "$setup" ]; then
    ls /tmp/stage/bundle.part* 2>/dev/null || { echo "no warp/mujoco and no .devK carried (../shared/tools/device_bundle.sh)"; exit 2; }
    echo "staged; call again carrying the next .devK"; exit 0
  fi
  bash "$setup" || exit 2
fi
if [ -f .devc/warp_cache.tar.xz ] && [ ! -e /tmp/.gpu_run_cache ]; then
  mkdir -p ~/.cache/warp && tar -C ~/.cache/warp -xJf .devc/warp_cache.tar.xz && touch /tmp/.gpu_run_cache
fi

case $what in
  cache) tar -C ~/.cache/warp -cf - . | xz -T0 -3 >"$OUT/warp_cache.tar.xz"; ls -l "$OUT/warp_cache.tar.xz"; exit ;;
  tests) [ $# -gt 0 ] || set -- -k "cuda or tiled or analytic or gpu" tests --ignore=tests/stress \
           --ignore=tests/test_ray_gpus.py --ignore=tests/test_myosuite.py --continue-on-collection-errors
         cmd=("$py" -m pytest -q -p no:cacheprovider -o addopts= "$@") ;;
  cli) cmd=("$py" -m physhand_mj.cli "$@") ;;
  *) [ -f "benchmarks/$what.py" ] || { echo "no benchmarks/$what.py (benchmarks/README.md lists them)"; exit 2; }
     cmd=("$py" "benchmarks/$what.py" "$@") ;;
esac
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
stamp=$(mktemp); t0=$SECONDS
log="$OUT/${what//\//_}_$(date +%H%M%S).log"
timeout "${GPU_RUN_LIMIT:-560}" "${cmd[@]}" 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}
echo "[$what] rc=$rc $((SECONDS - t0)) s (124: past GPU_RUN_LIMIT)"
# results written under docs/ (the scripts' default paths) come back flat: each call runs in a fresh copy
find docs -newer "$stamp" -type f \( -name '*.json' -o -name '*.csv' -o -name '*.png' -o -name '*.md' \) \
  -exec cp {} "$OUT/" \;
rm -f "$stamp"
if [ "$(find "$OUT" -maxdepth 1 -type f | wc -l)" -gt 8 ]; then
  (cd "$OUT" && t=results_$(date +%H%M%S).tgz && find . -maxdepth 1 -type f ! -name 'warp_cache.tar.xz' \
    ! -name 'results_*.tgz' -printf '%f\n' | tar -czf "/tmp/$t" -T - --remove-files && mv "/tmp/$t" .)
fi
exit "$rc"
