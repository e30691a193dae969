#!/usr/bin/env bash
# Simulate, on this machine (MuJoCo; the lent GPU machines have none), the runs that
# bench/gpu_check.sh's convergence stage trains and scores on: every run of
# scenarios/paper-cpu.yaml (the 1000-sample training run, both drives of E1-E3) for each seed
# given, packed (xz) into the git-ignored carry folder .gpu-carry-runs/ (seed-N.tar.xz and
# RUNS.json: checksums, sizes, sample counts, commit). Simulations are cached in
# runs/gpu-runs/seed-N. Prints the folder's size against the 64 MiB a device call carries with
# the working tree; run it before bench/gpu_wheels.sh, which leaves room for it in its last call.
# Usage: bench/gpu_runs.sh [SEED ...]   (default: 0 1)   MUJOCO_GL=egl is set if unset.
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL="${MUJOCO_GL:-egl}"
python="${PYTHON:-python3}"
seeds=("$@")
[ "${#seeds[@]}" -gt 0 ] || seeds=(0 1)
"$python" bench/gpu_converge.py pack --seeds "${seeds[@]}" --dest .gpu-carry-runs
runs=$(du -cb .gpu-carry-runs/* | tail -1 | cut -f1)
tree=$(git ls-files -z | xargs -0 du -cb 2>/dev/null | tail -1 | cut -f1)
echo ".gpu-carry-runs: $runs bytes ($(awk "BEGIN {printf \"%.2f\", $runs / 1048576}") MiB) for seeds ${seeds[*]};" \
    "working tree $(awk "BEGIN {printf \"%.2f\", $tree / 1048576}") MiB; carry limit 64 MiB per call"
