#!/bin/bash
# The GPU checks of docs/performance.md ("Measuring them on a GPU"), as parts that each fit one
# 10-minute call of a lent GPU machine (two of them fit its 15 minutes): the figures, the tests, and
# the same-numbers check on that machine's CPU. Each step runs under a hard time limit and its
# result goes to $OUT/log.txt as it comes (what is under $OUT comes back even when the call is cut
# off); a failing test is reported the moment it fails.
#
#   bash benchmarks/gpu_checks.sh prepare   # here, with PyPI: the missing packages as wheels in .whl/
#   bash benchmarks/gpu_checks.sh figures   # there, with .whl carried: the benchmarks (limits: 7 min)
#   bash benchmarks/gpu_checks.sh tests     # there, with .whl carried: tests/test_cuda.py (limits: 6.5 min)
#   bash benchmarks/gpu_checks.sh same-numbers  # there: the same-numbers tests on its CPU (an Intel Xeon,
#                                           # family 6, model 207 so far), under its torch
#
# The GPU machine has Python 3.12 with torch, numpy, scipy, matplotlib and tqdm, and no network;
# the project's other packages travel as wheels. Ray's wheel is over the size a call may carry, so
# it travels without its Java jars, its servers and its libraries: `import ray` works (EvoTorch
# imports it), `ray.init` does not, and none of these checks starts Ray (the sweeps of the list are
# left out). What travels is limited to 64 MiB: when the tracked files and .whl/ are over it, move
# docs/data out of the checkout for the call (no check reads it) and back after it.
set -u
WHEELS=.whl

part=${1:-}
case "$part" in prepare|figures|tests|same-numbers) ;; *) echo "usage: bash $0 prepare|figures|tests|same-numbers" >&2; exit 2;; esac

if [ "$part" = prepare ]; then
  exclude=$(git rev-parse --git-common-dir)/info/exclude
  mkdir -p "$WHEELS" "$(dirname "$exclude")" && { grep -qx "/$WHEELS/" "$exclude" 2>/dev/null || echo "/$WHEELS/" >> "$exclude"; }
  for package in neat-python==2.0.0 evotorch==0.6.1 gymnasium==1.4.0 pettingzoo==1.27.0 farama-notifications \
                 cma jsonschema jsonschema-specifications referencing rpds-py ray==2.60.0; do
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
      -d "$WHEELS" "$package" || exit 1
  done
  python3 - "$WHEELS" <<'PY' || exit 1
import sys, zipfile
from pathlib import Path
folder = Path(sys.argv[1])
wheel = next(folder.glob("ray-*.whl"))
left_out = ("ray/jars/", "ray/core/src/ray/gcs/gcs_server", "ray/core/src/ray/raylet/raylet", "ray/dashboard/",
            "ray/rllib/", "ray/serve/", "ray/llm/", "ray/data/", "ray/train/", "ray/tune/")
with zipfile.ZipFile(wheel) as full, zipfile.ZipFile(folder / "ray-import-only.zip", "w", zipfile.ZIP_DEFLATED) as out:
    for item in full.infolist():
        if not item.filename.startswith(left_out):
            out.writestr(item, full.read(item.filename))
wheel.unlink()
PY
  du -sh "$WHEELS"
  exit 0
fi

export PYTHONUNBUFFERED=1
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site "$WHEELS"/*.whl \
  && python3 -m zipfile -e "$WHEELS/ray-import-only.zip" /tmp/site || { echo "setup failed"; exit 1; }
export PYTHONPATH=/tmp/site:$PWD
LOG=$OUT/log.txt FULL=$OUT/full.txt
{ date -u; nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
  python3 -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.get_device_name())"
  lscpu | grep -m1 "Model name"; nproc; grep -m1 -ow "avx2\|avx512f\|amx_tile" /proc/cpuinfo | sort -u | xargs echo "CPU:"
} 2>&1 | tee "$LOG"

# step SECONDS COMMAND...: the command under a hard limit (killed 10 s after it), its output in
# full.txt and its last lines in log.txt
step() {
  local limit=$1; shift
  echo "### $(date -u +%T) [$limit s] $*" | tee -a "$LOG"
  timeout -k 10 "$limit" "$@" > "$OUT/step.txt" 2>&1
  local status=$?
  cat "$OUT/step.txt" >> "$FULL"
  tail -n 12 "$OUT/step.txt" | tee -a "$LOG"
  echo "### exit status $status" | tee -a "$LOG"
}
PYTEST="python3 -m pytest -n 0 -q -p no:cacheprovider -o addopts= -rfE --tb=short -p benchmarks.report_failures_at_once"

BENCH="python3 -m lifelong_evo.bench --device cuda"
if [ "$part" = figures ]; then
  # the environment eager and compiled, each with and without CUDA graphs, in one sitting; then the
  # optimisers (each eager, then compiled). A cold compile takes most of a minute.
  step 25 $BENCH --also []
  step 25 $BENCH --also [] --cuda-graphs
  step 80 $BENCH --compile --also []
  step 80 $BENCH --compile --also [] --cuda-graphs
  step 110 $BENCH --compile --algo neat
  step 100 $BENCH --compile --algo openai-es
elif [ "$part" = same-numbers ]; then
  # on the CPU: where sep-CMA-ES's update first differs from the stored trace (none: the same
  # trace), then the stored bytes under every speed setting and the portable functions' checks
  step 40 python3 -m benchmarks.trace_es_update --against tests/data/same-numbers/sep-cmaes-update-trace.txt
  step 300 $PYTEST tests/test_same_numbers_anywhere.py tests/test_numerics.py
else
  # the compiled capture, which once hung, last
  step 200 $PYTEST tests/test_cuda.py -k "not cuda_graph"
  step 50 $PYTEST tests/test_cuda.py -k "cuda_graph and not compiled"
  step 140 $PYTEST tests/test_cuda.py -k "cuda_graph and compiled"
fi
echo "### end $(date -u +%T)" | tee -a "$LOG"
