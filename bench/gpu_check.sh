#!/usr/bin/env bash
# Prove a GPU machine in one command (<= 9 minutes on an H100 / H200; GPU_CHECK_BUDGET seconds,
# default 540, from the start of the script):
#   1. make vitaplace importable (VITAPLACE_SKIP_INSTALL=1: as it is). With the carry folders of bench/gpu_wheels.sh present
#      (.gpu-carry-N/: a trimmed warp-lang in parts, pydantic's wheels; the lent GPU machines
#      reach no package registry): unpack them into a private folder and expose this source
#      tree there as the package vitaplace (with its plugin entry points), nothing built.
#      Otherwise pip install -e ".[test]" torch pytest-xdist;
#   2. look for a CUDA device; without one, say so (DIR/no-cuda.txt), run what the CPU can:
#      the emulated tensor-core tests (tests/kernels/test_tensorcores.py) and a tiny convergence
#      stage (epoch cap 1, 5 inference steps; on .gpu-carry-runs if present, else on tiny runs it
#      simulates, which needs MuJoCo), write the summary, exit 3;
#   3. run the CUDA half of the kernel, network and tensor-core tests (pytest -m cuda; <= 150 s);
#   4. benchmark the training minibatch in float32, tf32 and bf16: cuBLAS GEMMs vs the
#      PyTorch step vs the Warp backend of the same precision, then >= 50 epochs of
#      paper-shape training per precision (bench/pc_step.py --device cuda; <= 240 s);
#   5. the convergence check at study size with what is left (bench/gpu_converge.py: L, L-V, L-T
#      of scenarios/paper-cpu.yaml on the recorded runs carried in .gpu-carry-runs/ (bench/gpu_runs.sh),
#      epoch cap 1000 (the energy criterion stops them), 3000 inference steps; seed 0, then
#      further carried seeds while the time allows) -> DIR/converge.json;
#   6. write DIR/SUMMARY.md; DIR/bench.json is the record (seconds per epoch of each precision
#      under "s_per_epoch"), DIR/converge.json the convergence check's.
# Usage: bench/gpu_check.sh [DIR]   (default DIR: gpu-check; on a lent machine "$OUT/gpu-check",
# whose files come back). Each stage has a time limit, so a summary is written even when one
# runs over; the exit status is non-zero if any failed. GPU_CHECK_STAGES (default "tests bench
# converge") picks the CUDA stages, e.g. GPU_CHECK_STAGES=converge for a rerun of that one alone.
set -uo pipefail
cd "$(dirname "$0")/.."
dir="${1:-gpu-check}"
mkdir -p "$dir"
: > "$dir/stages.txt"
rm -f "$dir/no-cuda.txt"
jobs="$(nproc)"
export PYTHONUNBUFFERED=1
python="${PYTHON:-python3}"
budget="${GPU_CHECK_BUDGET:-540}"
status=0
left() { echo $((budget - SECONDS)); }
limit() {  # limit SECONDS: that, or what is left of the budget less RESERVE (default 0) if less
    local l=$(( $(left) - ${2:-0} ))
    [ "$l" -lt "$1" ] && echo $((l > 10 ? l : 10)) || echo "$1"
}
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
    read -r parts sum < .gpu-carry-[0-9]*/MANIFEST || return 1
    [ "$(ls .gpu-carry-[0-9]*/warp.zip.part-* | wc -l)" -eq "$parts" ] || return 1
    cat .gpu-carry-[0-9]*/warp.zip.part-* > /tmp/vitaplace-warp.zip || return 1
    [ "$(sha256sum < /tmp/vitaplace-warp.zip | cut -d' ' -f1)" = "$sum" ] || return 1
    unzip -q -o /tmp/vitaplace-warp.zip -d "$site" || return 1
    for wheel in .gpu-carry-[0-9]*/*.whl; do unzip -q -o "$wheel" -d "$site" || return 1; done
    # the pipeline's dependencies (bench/gpu_wheels.sh, deps/): only those whose module the device lacks
    local module
    for wheel in .gpu-carry-[0-9]*/deps/*.whl; do
        [ -e "$wheel" ] || continue
        case "$(basename "$wheel")" in
            fonttools-*) module=fontTools ;; pillow-*) module=PIL ;; python_dateutil-*) module=dateutil ;;
            pyyaml-*|PyYAML-*) module=yaml ;; *) module="$(basename "$wheel" | cut -d- -f1)" ;;
        esac
        "$python" -c "import $module" 2> /dev/null && continue
        unzip -q -o "$wheel" -d "$site" || return 1
        echo "$module" >> "$dir/carried-deps.txt"
    done
    for pkg in engine kernels plugins scenarios; do ln -sfn "$PWD/$pkg" "$site/vitaplace/$pkg"; done
    for module in api/*.py; do ln -sfn "$PWD/$module" "$site/vitaplace/$(basename "$module")"; done
    # a distribution record, so that importlib.metadata finds vitaplace's plugin entry points
    "$python" - "$site" <<'PY' || return 1
import sys, tomllib
from pathlib import Path
project = tomllib.loads(Path("pyproject.toml").read_text())["project"]
info = Path(sys.argv[1]) / f"vitaplace-{project['version']}.dist-info"
info.mkdir()
(info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: vitaplace\nVersion: {project['version']}\n")
groups = project.get("entry-points", {})
(info / "entry_points.txt").write_text("".join(
    f"[{group}]\n" + "".join(f"{name} = {target}\n" for name, target in eps.items()) + "\n"
    for group, eps in groups.items()))
PY
    export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}"
}
if [ -n "${VITAPLACE_SKIP_INSTALL:-}" ]; then
    :
elif compgen -G ".gpu-carry-[0-9]*/MANIFEST" > /dev/null; then
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
    # the convergence stage's plumbing, tiny: recorded runs in, results file and summary table out
    runs=.gpu-carry-runs
    if [ ! -f "$runs/RUNS.json" ]; then
        runs="$dir/tiny-runs"
        stage converge-pack 300 "$python" bench/gpu_converge.py pack --tiny --seeds 0 --dest "$runs" \
            --sim-root "$dir/tiny-sim"
    fi
    stage converge 600 "$python" bench/gpu_converge.py run --runs "$runs" --out "$dir" --seeds 0 \
        --epochs 1 --max-steps 5 --budget 540
    "$python" bench/gpu_summary.py "$dir" > "$dir/SUMMARY.md"
    cat "$dir/SUMMARY.md"
    exit 3
fi
only="${GPU_CHECK_STAGES:-tests bench converge}"  # e.g. GPU_CHECK_STAGES=converge: that stage alone, all the budget
want() { [[ " $only " == *" $1 "* ]]; }
want tests && stage tests "$(limit 150)" "$python" -m pytest -q -p no:cacheprovider -m cuda -n "$jobs" \
    tests/kernels/test_kernels.py tests/kernels/test_pc.py tests/kernels/test_tensorcores.py
want bench && stage bench "$(limit 240 60)" "$python" bench/pc_step.py --device cuda --repeat 5 --epochs 50 --json "$dir/bench.json"
# what is left, less 15 s for the summary; the script's own budget 20 s under that, so that it
# stops its training processes and writes DIR/converge.json itself
conv=$(( $(left) - 15 ))
[ "$conv" -ge 60 ] || conv=60
want converge && stage converge "$conv" "$python" bench/gpu_converge.py run --runs .gpu-carry-runs --out "$dir" --budget $((conv - 20))
"$python" bench/gpu_summary.py "$dir" > "$dir/SUMMARY.md" || status=1
cat "$dir/SUMMARY.md"
exit "$status"
