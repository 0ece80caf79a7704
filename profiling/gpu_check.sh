#!/usr/bin/env bash
# The GPU check of the gsplat backend, in one call (docs/architecture.md, the gsplat rasterizer): install the wheels in
# whl/, time gsplat's JIT compile, run the agreement tests, then KITTI 06 at full resolution with
# `none` and `pocket` on gsplat and on the torch reference, and summarise each run.
# Run it from a folder holding the checkout's files, whl/ (gsplat, pocketbench and the missing
# dependencies as wheels) and kitti/ (a KITTI root with sequence 06), on a machine with CUDA, nvcc
# and ninja. Every step has its own timeout, cut to what is left before DEADLINE_S (from the start)
# less what the steps after it are guaranteed, so a slow step cannot eat the whole call.
#   OUT=DIR bash profiling/gpu_check.sh [TORCH_LAST_FRAME]
# TORCH_LAST_FRAME: the torch runs stop at that frame index (default: all frames).
# EVAL_EVERY: every run scores every N-th frame (default 5). The image metrics run on the CPU in float64
# (torchmetrics' SSIM and MS-SSIM), a few seconds a frame at 1226x370 even beside an H100, so scoring all
# 51 frames outlasts the call (reports/gpu/README.md).
set -u -o pipefail
OUT=${OUT:-/tmp/gpu_check}
RUNS=${RUNS:-/tmp/gpu_runs}
SITE=${SITE:-/tmp/site}
mkdir -p "$OUT" "$RUNS"
TORCH_LAST=${1:-}
export PYTHONUNBUFFERED=1 MAX_JOBS=${MAX_JOBS:-16} TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
T_GS=${T_GS:-120} T_TORCH=${T_TORCH:-100} T_COMPILE=${T_COMPILE:-330} T_TESTS=${T_TESTS:-90}
DEADLINE_S=${DEADLINE_S:-100000}
t0=$SECONDS
stamp() { echo "[$((SECONDS - t0)) s] $*"; }
limit() {  # CAP RESERVE: CAP seconds, or what is left before the deadline less RESERVE (at least 5)
  local left=$((DEADLINE_S - (SECONDS - t0) - $2))
  [ "$left" -lt "$1" ] && echo $((left > 5 ? left : 5)) || echo "$1"
}

stamp "install wheels"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" whl/*.whl \
  || { echo "error: wheel install failed"; exit 3; }
export PYTHONPATH="$SITE"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
nproc

stamp "gsplat JIT compile"
timeout "$(limit "$T_COMPILE" 170)" python3 - <<'EOF'
import time
import torch
t = time.time()
from gsplat.cuda._backend import _C
print(f"gsplat compile+load: {time.time() - t:.1f} s, loaded: {_C is not None}; torch {torch.__version__}, "
      f"CUDA {torch.version.cuda}, {torch.cuda.get_device_name()}")
EOF
stamp "compile step rc=$?"
so=$(ls ~/.cache/torch_extensions/*/gsplat_cuda/gsplat_cuda.so 2>/dev/null | head -n 1)
[ -n "$so" ] && ls -l "$so" && gzip -c "$so" | split -b 15M - "$OUT/gsplat_cuda.so.gz." && ls -l "$OUT"

stamp "agreement tests"
timeout "$(limit "$T_TESTS" 140)" python3 -m pytest -q -p no:cacheprovider -rs tests/slam/test_raster_gsplat.py \
  tests/slam/test_raster_fused.py::test_backend_choice 2>&1 | tee "$OUT/tests.log" | tail -40
stamp "tests rc=$?"

run() {  # NAME CAP RESERVE OVERRIDES...
  local name=$1 cap
  cap=$(limit "$2" "$3")
  shift 3
  stamp "run $name: $*"
  timeout "$cap" python3 -m bench "$@" dataset=kitti dataset.root="$PWD/kitti" seq=06 dataset.downscale=1 threads=8 \
    eval.every="${EVAL_EVERY:-5}" hydra.run.dir="$RUNS/$name" >"$RUNS/$name.out" 2>"$RUNS/$name.err"
  stamp "run $name rc=$?"
  tail -n 4 "$RUNS/$name.err"
  python3 profiling/gpu_summary.py "$RUNS/$name" | tee -a "$OUT/summary.txt"
}
run gsplat_none "$T_GS" 80 slam.raster_backend=gsplat
run gsplat_pocket "$T_GS" 30 +strategy=pocket slam.raster_backend=gsplat
last=()
[ -n "$TORCH_LAST" ] && last=("dataset.last=$TORCH_LAST")
run torch_none "$T_TORCH" 15 slam.raster_backend=torch "${last[@]}"
run torch_pocket "$T_TORCH" 3 +strategy=pocket slam.raster_backend=torch "${last[@]}"

tar czf "$OUT/runs.tgz" -C "$RUNS" --exclude='*.ply' --exclude='*.png' --exclude='*.pt' . 2>/dev/null
stamp "done"
