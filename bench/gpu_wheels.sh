#!/usr/bin/env bash
# Prepare, on a machine with a package registry, what bench/gpu_check.sh needs on a lent GPU
# machine that reaches none (its image has PyTorch, CuPy and JAX, not warp-lang or pydantic):
# the warp-lang wheel of the version installed here, trimmed to what CUDA needs (no warp-clang.so,
# Warp's CPU compiler, which it loads only if present; no examples or tests) and split into
# parts, plus the wheels of pydantic and its dependencies, for CPython 3.12 on x86-64 Linux,
# and in deps/ those of what the pipeline (the convergence stage's `vitaplace evaluate`) imports
# beyond numpy and scipy (h5py, matplotlib and its dependencies, pluggy, PyYAML, tqdm,
# threadpoolctl): bench/gpu_check.sh unpacks one of those only if the device lacks its module.
# A device call carries at most 64 MiB with the working tree, so the parts go into numbered
# folders .gpu-carry-1, .gpu-carry-2, ... (git-ignored), one per call: every call but the last
# only carries its folder (the machine keeps it while it stays warm, 30 s), the last carries
# its own and runs the check. The recorded runs of bench/gpu_runs.sh (.gpu-carry-runs/, for the
# convergence stage) travel with the last call: run that script first, so that their size is
# left free in every part. The script prints those calls.
# Usage: bench/gpu_wheels.sh [MiB per call, default 64]
set -euo pipefail
cd "$(dirname "$0")/.."
limit_mib="${1:-64}"
python="${PYTHON:-python3}"
versions="$("$python" - <<'PY'
from importlib.metadata import version
print(" ".join(f"{n}=={version(n)}" for n in ("warp-lang", "pydantic", "pydantic-core", "annotated-types", "typing-inspection")))
PY
)"
deps="$("$python" - <<'PY'
from importlib.metadata import version
names = ("h5py", "matplotlib", "contourpy", "cycler", "fonttools", "kiwisolver", "pillow", "pyparsing",
         "python-dateutil", "six", "packaging", "pluggy", "PyYAML", "tqdm", "threadpoolctl")
print(" ".join(f"{n}=={version(n)}" for n in names))
PY
)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
# shellcheck disable=SC2086
"$python" -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$tmp" $versions
mkdir -p "$tmp/deps"
# shellcheck disable=SC2086
"$python" -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$tmp/deps" $deps
"$python" - "$tmp" <<'PY'
import sys, zipfile, glob
tmp = sys.argv[1]
(wheel,) = glob.glob(f"{tmp}/warp_lang-*.whl")
drop = ("warp/bin/warp-clang.so", "warp/examples/", "warp/tests/")
with zipfile.ZipFile(wheel) as zin, zipfile.ZipFile(f"{tmp}/warp.zip", "w", zipfile.ZIP_DEFLATED) as zout:
    for item in zin.infolist():
        if not item.filename.startswith(drop):
            zout.writestr(item, zin.read(item.filename))
PY
rm -rf .gpu-carry-[0-9]*
runs_bytes=0 runs_dir=
if [ -d .gpu-carry-runs ]; then runs_bytes=$(du -sb .gpu-carry-runs | cut -f1); runs_dir=.gpu-carry-runs; fi
tree_bytes=$(git ls-files -z | xargs -0 du -cb 2>/dev/null | tail -1 | cut -f1)
others=$(du -cb "$tmp"/*.whl "$tmp"/deps/*.whl | tail -1 | cut -f1)
others=$((others - $(du -b "$tmp"/warp_lang-*.whl | cut -f1)))
capacity=$((limit_mib * 1048576 - tree_bytes - 2 * 1048576))  # per call, beside the tree; 2 MiB to spare
size=$(du -b "$tmp/warp.zip" | cut -f1)
# full-size parts of warp.zip, one per call; the last call carries the rest of it with the other
# wheels and the runs, or, if those do not fit beside it, a call of its own
chunks=$(( (size + capacity - 1) / capacity ))
rest=$((size - (chunks - 1) * capacity))
parts=$chunks
[ $((rest + others + runs_bytes)) -le "$capacity" ] || parts=$((chunks + 1))
split -b "$capacity" -d -a 2 "$tmp/warp.zip" "$tmp/warp.zip.part-"
for i in $(seq 1 "$parts"); do mkdir -p ".gpu-carry-$i"; done
for i in $(seq 1 "$chunks"); do
    mv "$tmp/warp.zip.part-$(printf '%02d' $((i - 1)))" ".gpu-carry-$i/"
done
echo "$chunks $(sha256sum < "$tmp/warp.zip" | cut -d' ' -f1)" > ".gpu-carry-$parts/MANIFEST"  # warp.zip's parts, SHA-256
for w in "$tmp"/*.whl; do
    case "$(basename "$w")" in warp_lang-*) ;; *) cp "$w" ".gpu-carry-$parts/" ;; esac
done
cp -r "$tmp/deps" ".gpu-carry-$parts/"
du -sb .gpu-carry-* | awk '{printf "%-18s %10d bytes  %6.2f MiB\n", $2, $1, $1 / 1048576}'
echo "working tree: $tree_bytes bytes; the last call carries $(du -cb .gpu-carry-"$parts" $runs_dir \
    | tail -1 | cut -f1) bytes of carry folders with it (limit $limit_mib MiB)"
last="\".gpu-carry-$parts\""
[ -z "$runs_dir" ] || last="$last, \"$runs_dir\""
echo
echo "device calls (the run tool), back to back:"
for i in $(seq 1 $((parts - 1))); do
    echo "  run(carry=[\".gpu-carry-$i\"], command=\"ls .gpu-carry-$i\", timeout_s=60)"
done
echo "  run(carry=[$last], command=\"bench/gpu_check.sh \$OUT/gpu-check\", timeout_s=600)"
