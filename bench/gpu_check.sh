#!/usr/bin/env bash
# Prove a GPU machine in one command (< 10 minutes on an H100):
#   1. install vitaplace with its test extra, PyTorch and pytest-xdist (skip: VITAPLACE_SKIP_INSTALL=1);
#   2. run the CUDA half of the kernel and network tests (pytest -m cuda), in parallel workers;
#   3. sweep the Warp kernels' tile sizes at the paper's shapes (bench/tile_sweep.py);
#   4. benchmark the training step with the sweep's winners: cuBLAS GEMMs vs a PyTorch-CUDA
#      step vs the Warp backend, in float32 and in TF32, then a timed training projected to
#      the paper's 10000 epochs and test-time inference of 300 samples x 3000 steps
#      (bench/pc_step.py --device cuda);
#   5. write DIR/SUMMARY.md from the logs and JSON files beside it.
# Usage: bench/gpu_check.sh [DIR]   (default DIR: gpu-check). Each stage has a time limit, so
# a summary is written even when one runs over; its exit status is non-zero if any failed.
set -uo pipefail
cd "$(dirname "$0")/.."
dir="${1:-gpu-check}"
mkdir -p "$dir"
jobs="$(nproc)"
export PYTHONUNBUFFERED=1
python="${PYTHON:-python3}"
if [ -z "${VITAPLACE_SKIP_INSTALL:-}" ]; then
    "$python" -m pip install --quiet -e ".[test]" torch pytest-xdist || exit 1
fi
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.max.sm --format=csv > "$dir/nvidia-smi.csv" 2>&1
status=0
stage() {  # stage NAME SECONDS COMMAND...: run with a time limit, log to DIR/NAME.log
    local name="$1" limit="$2"
    shift 2
    local t0=$SECONDS
    timeout "$limit" "$@" > "$dir/$name.log" 2>&1
    local rc=$?
    echo "$name rc=$rc seconds=$((SECONDS - t0))" | tee -a "$dir/stages.txt"
    [ "$rc" -eq 0 ] || status=1
}
: > "$dir/stages.txt"
stage tests 180 "$python" -m pytest -q -p no:cacheprovider -m cuda -n "$jobs" tests/test_kernels.py tests/test_pc.py
stage sweep 150 "$python" bench/tile_sweep.py --device cuda --splits 1 8 --compile-limit 110 --json "$dir/sweep.json"
tiles=()
[ -s "$dir/sweep.json" ] && tiles=(--tiles "$dir/sweep.json")
stage bench 200 "$python" bench/pc_step.py --device cuda --repeat 5 "${tiles[@]}" --json "$dir/bench.json"
"$python" bench/gpu_summary.py "$dir" > "$dir/SUMMARY.md" || status=1
cat "$dir/SUMMARY.md"
exit "$status"
