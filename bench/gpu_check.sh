#!/usr/bin/env bash
# Prove a GPU machine in one command (<= 9 minutes on an H100 / H200):
#   1. make vitaplace importable (VITAPLACE_SKIP_INSTALL=1: as it is). With the carry folders of bench/gpu_wheels.sh present
#      (.gpu-carry-*/: a trimmed warp-lang in parts, pydantic's wheels; the lent GPU machines
#      reach no package registry): unpack them into a private folder and expose this source
#      tree there as the package vitaplace, nothing built. Otherwise pip install -e ".[test]"
#      torch pytest-xdist;
#   2. look for a CUDA device; without one, say so (DIR/no-cuda.txt), run what the CPU can:
#      the emulated tensor-core tests (tests/kernels/test_tensorcores.py), write the summary, exit 3;
#   3. run the CUDA half of the kernel, network and tensor-core tests (pytest -m cuda);
#   4. benchmark the training minibatch in float32, tf32 and bf16: cuBLAS GEMMs vs the
#      PyTorch step vs the Warp backend of the same precision, then >= 50 epochs of
#      paper-shape training per precision (bench/pc_step.py --device cuda);
#   5. write DIR/SUMMARY.md; DIR/bench.json is the record (seconds per epoch of each precision
#      under "s_per_epoch").
# Usage: bench/gpu_check.sh [DIR]   (default DIR: gpu-check; on a lent machine "$OUT/gpu-check",
# whose files come back). Each stage has a time limit, so a summary is written even when one
# runs over; the exit status is non-zero if any failed.
set -uo pipefail
cd "$(dirname "$0")/.."
dir="${1:-gpu-check}"
mkdir -p "$dir"
: > "$dir/stages.txt"
rm -f "$dir/no-cuda.txt"
jobs="$(nproc)"
export PYTHONUNBUFFERED=1
python="${PYTHON:-python3}"
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
unpack_carried() {  # the carry folders of bench/gpu_wheels.sh -> a private site folder
    local site=/tmp/vitaplace-site
    rm -rf "$site" && mkdir -p "$site/vitaplace" || return 1
    local parts sum
    read -r parts sum < .gpu-carry-*/MANIFEST || return 1
    [ "$(ls .gpu-carry-*/warp.zip.part-* | wc -l)" -eq "$parts" ] || return 1
    cat .gpu-carry-*/warp.zip.part-* > /tmp/vitaplace-warp.zip || return 1
    [ "$(sha256sum < /tmp/vitaplace-warp.zip | cut -d' ' -f1)" = "$sum" ] || return 1
    unzip -q -o /tmp/vitaplace-warp.zip -d "$site" || return 1
    for wheel in .gpu-carry-*/*.whl; do unzip -q -o "$wheel" -d "$site" || return 1; done
    for pkg in engine kernels plugins scenarios; do ln -sfn "$PWD/$pkg" "$site/vitaplace/$pkg"; done
    export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}"
}
if [ -n "${VITAPLACE_SKIP_INSTALL:-}" ]; then
    :
elif compgen -G ".gpu-carry-*/MANIFEST" > /dev/null; then
    t0=$SECONDS
    unpack_carried || { echo "install rc=1: the carried parts are incomplete or corrupt (each .gpu-carry-N must" \
        "be carried by its own call while the machine stays warm; bench/gpu_wheels.sh)" | tee -a "$dir/stages.txt"; exit 1; }
    echo "install rc=0 seconds=$((SECONDS - t0)) (carried wheels)" | tee -a "$dir/stages.txt"
else
    stage install 300 "$python" -m pip install -e ".[test]" torch pytest-xdist
    [ "$status" -eq 0 ] || exit 1
fi
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.max.sm --format=csv > "$dir/nvidia-smi.csv" 2>&1 \
    || rm -f "$dir/nvidia-smi.csv"
if ! "$python" -c "import sys; from vitaplace.engine.network.selection import cuda_available; sys.exit(not cuda_available())"; then
    echo "no CUDA device found (no NVIDIA driver, or Warp sees no GPU): only the CPU-runnable parts ran" \
        | tee "$dir/no-cuda.txt"
    stage cpu-tests 600 "$python" -m pytest -q -p no:cacheprovider tests/kernels/test_tensorcores.py
    "$python" bench/gpu_summary.py "$dir" > "$dir/SUMMARY.md"
    cat "$dir/SUMMARY.md"
    exit 3
fi
stage tests 180 "$python" -m pytest -q -p no:cacheprovider -m cuda -n "$jobs" \
    tests/kernels/test_kernels.py tests/kernels/test_pc.py tests/kernels/test_tensorcores.py
stage bench 300 "$python" bench/pc_step.py --device cuda --repeat 5 --epochs 50 --json "$dir/bench.json"
"$python" bench/gpu_summary.py "$dir" > "$dir/SUMMARY.md" || status=1
cat "$dir/SUMMARY.md"
exit "$status"
