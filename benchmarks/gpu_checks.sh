#!/bin/bash
# The GPU checks of docs/performance.md ("Measuring them on a GPU") that fit one 10-minute call of a
# lent GPU machine, most wanted first, each under a hard time limit, each result written to
# $OUT/log.txt as it comes (what is under $OUT comes back even when the call is cut off).
#
#   bash benchmarks/gpu_checks.sh prepare   # here, with PyPI: the missing packages as wheels in .whl/
#   bash benchmarks/gpu_checks.sh           # there, with .whl carried: the checks
#
# The GPU machine has Python 3.12 with torch, numpy, scipy, matplotlib and tqdm, and no network;
# the project's other packages travel as wheels. Ray's wheel is over the size a call may carry, so
# it travels without its Java jars, its servers and its libraries: `import ray` works, `ray.init`
# does not, and none of these checks starts Ray (the sweeps of the list are left out).
set -u
WHEELS=.whl

if [ "${1:-}" = prepare ]; then
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
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$WHEELS"/*.whl \
  && python3 -m zipfile -e "$WHEELS/ray-import-only.zip" /tmp/site || { echo "setup failed"; exit 1; }
export PYTHONPATH=/tmp/site:$PWD
LOG=$OUT/log.txt FULL=$OUT/full.txt
{ date -u; nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
  python3 -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.get_device_name())"
  lscpu | grep -m1 "Model name"; nproc; } 2>&1 | tee "$LOG"

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
PYTEST="python3 -m pytest -n 0 -q -p no:cacheprovider -o addopts= -rfE --tb=short"

# the goals' figures first; then the tests; the compiled capture, which once hung, last
step 50 python3 -m lifelong_evo.bench --device cuda --compile --also []
step 65 python3 -m lifelong_evo.bench --device cuda --compile --algo neat
step 65 python3 -m lifelong_evo.bench --device cuda --compile --algo openai-es
step 140 $PYTEST tests/test_cuda.py -k "not cuda_graph"
step 50 python3 -m lifelong_evo.bench --device cuda --also [] --cuda-graphs
step 60 $PYTEST tests/test_cuda.py -k "cuda_graph and not compiled"
step 60 python3 -m lifelong_evo.bench --device cuda --compile --also [] --cuda-graphs
step 60 $PYTEST tests/test_cuda.py -k "cuda_graph and compiled"
echo "### end $(date -u +%T)" | tee -a "$LOG"
