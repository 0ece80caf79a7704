#!/usr/bin/env bash
# The GPU check of the gsplat backend, in one call (docs/architecture.md, the gsplat rasterizer; reports/gpu/).
# Installs the wheels in whl/, restores the commit's git record (so every run records its commit and a clean
# tree), times gsplat's JIT compile, runs the agreement tests, profiles a short run phase by phase
# (profiling/gpu_profile.py), then runs KITTI 06 at full resolution with `none` and `pocket`, and copies each
# run dir (without its map) under $OUT/runs for `python -m bench.report` on the development machine.
#
# Run it from a folder holding the checkout's files, with beside them: whl/ (gsplat, pocketbench and the missing
# dependencies as wheels), kitti/ (a KITTI root with sequence 06) and, optionally, git/ (a blob-less clone of
# the checkout's commit: `git clone --bare --depth 1 --filter=blob:none file://$PWD git`), on a machine with
# CUDA, nvcc and ninja. Every step has its own timeout, cut to what is left before DEADLINE_S (from the start)
# less what the steps after it are guaranteed, so a slow step cannot eat the whole call.
#   OUT=DIR MODE=before|after bash profiling/gpu_check.sh
# MODE=before: the profile, then the default preset's `none` and `pocket` scored as before scoring moved to the
#   run's device (every 5th frame, on the host: eval.every=5 eval.device=cpu).
# MODE=after: the profile, the default preset's runs scoring every frame on the GPU, then the faithful preset's
#   (slam=faithful_fit dataset.stride=2 eval.protocol=splatam) at 1/2 resolution, as the CPU studies run it.
set -u -o pipefail
OUT=${OUT:-/tmp/gpu_check}
MODE=${MODE:-after}
RUNS=${RUNS:-/tmp/gpu_runs}
SITE=${SITE:-/tmp/site}
WHL=${WHL:-whl} KITTI=${KITTI:-kitti} GITDIR=${GITDIR:-git}
mkdir -p "$OUT" "$RUNS"
export PYTHONUNBUFFERED=1 MAX_JOBS=${MAX_JOBS:-16} TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
T_RUN=${T_RUN:-150} T_FAITH=${T_FAITH:-240} T_COMPILE=${T_COMPILE:-200} T_TESTS=${T_TESTS:-60} T_PROF=${T_PROF:-120}
DEADLINE_S=${DEADLINE_S:-100000}
t0=$SECONDS
stamp() { echo "[$((SECONDS - t0)) s] $*"; }
limit() {  # CAP RESERVE: CAP seconds, or what is left before the deadline less RESERVE (at least 5)
  local left=$((DEADLINE_S - (SECONDS - t0) - $2))
  [ "$left" -lt "$1" ] && echo $((left > 5 ? left : 5)) || echo "$1"
}

stamp "install wheels"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" "$WHL"/*.whl \
  || { echo "error: wheel install failed"; exit 3; }
export PYTHONPATH="$SITE"
if [ -d "$GITDIR" ]; then  # the commit's record: files the call did not carry are marked, not counted as changes
  export GIT_DIR="$PWD/$GITDIR" GIT_WORK_TREE="$PWD"
  git read-tree HEAD && git ls-files -z -d | xargs -0 -r git update-index --skip-worktree
  echo "git: $(git rev-parse HEAD), skipped (not carried): $(git ls-files -v | grep -c '^S'), changed:"
  git status --porcelain --untracked-files=no | head -5
fi
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.max.sm --format=csv,noheader
nproc

stamp "gsplat JIT compile"
timeout "$(limit "$T_COMPILE" 320)" python3 - <<'EOF'
import time
import torch
t = time.time()
from gsplat.cuda._backend import _C
print(f"gsplat compile+load: {time.time() - t:.1f} s, loaded: {_C is not None}; torch {torch.__version__}, "
      f"CUDA {torch.version.cuda}, {torch.cuda.get_device_name()}")
EOF
stamp "compile step rc=$?"

BASE=(dataset=kitti "dataset.root=$PWD/$KITTI" seq=06 threads=8 slam.raster_backend=gsplat progress=false)
stamp "agreement tests"
timeout "$(limit "$T_TESTS" 300)" python3 -m pytest -q -p no:cacheprovider -rs tests/slam/test_raster_gsplat.py \
  tests/slam/test_raster_fused.py::test_backend_choice 2>&1 | tail -5
stamp "tests rc=$?"
# the statistics kernel (slam.gsplat_stats=auto picks it on CUDA): if it disagrees with the torch chunks, the runs
# below use the torch chunks, and the log says so
if ! timeout 60 python3 -m pytest -q -p no:cacheprovider tests/slam/test_raster_gsplat.py -k triton_statistics_agree \
  >/dev/null 2>&1; then
  echo "warning: the Triton statistics kernel failed its agreement test: runs use slam.gsplat_stats=torch"
  BASE+=(slam.gsplat_stats=torch)
fi
stamp "profile ($MODE)"
prof_extra=()
[ "$MODE" = before ] && prof_extra=(eval.device=cpu)
timeout "$(limit "$T_PROF" 250)" python3 profiling/gpu_profile.py --out "$OUT/profile_$MODE" --syncs --sync-frames 3 -- \
  "${BASE[@]}" dataset.downscale=1 dataset.last=11 eval.every=5 "${prof_extra[@]}" 2>&1 | grep -v '^USDT' | tail -30
stamp "profile rc=$?"
if [ "$MODE" = after ]; then  # the same run with determinism=fast: what torch's deterministic CUDA kernels cost
  timeout "$(limit 60 210)" python3 profiling/gpu_profile.py --out "$OUT/profile_fast" -- \
    "${BASE[@]}" dataset.downscale=1 dataset.last=11 eval.every=5 determinism=fast 2>&1 | grep -v '^USDT' | tail -9
  stamp "profile fast rc=$?"
fi

run() {  # NAME CAP RESERVE OVERRIDES...
  local name=$1 cap
  cap=$(limit "$2" "$3")
  shift 3
  stamp "run $name: $*"
  timeout "$cap" python3 -m bench "${BASE[@]}" "$@" hydra.run.dir="$RUNS/$name" >"$RUNS/$name.out" 2>"$RUNS/$name.err"
  stamp "run $name rc=$?"
  tail -n 2 "$RUNS/$name.err"
  python3 profiling/gpu_summary.py "$RUNS/$name" | tee -a "$OUT/summary.txt"
}
if [ "$MODE" = before ]; then
  run default_none_before "$T_RUN" 100 dataset.downscale=1 eval.every=5 eval.device=cpu
  run default_pocket_before "$T_RUN" 5 dataset.downscale=1 eval.every=5 eval.device=cpu +strategy=pocket
else
  FAITH=(slam=faithful_fit dataset.stride=2 eval.protocol=splatam)
  run default_none "$T_RUN" 160 dataset.downscale=1
  run default_pocket "$T_RUN" 120 dataset.downscale=1 +strategy=pocket
  run faithful_half_none "$T_FAITH" 60 dataset.downscale=2 "${FAITH[@]}"
  run faithful_half_pocket "$T_FAITH" 5 dataset.downscale=2 "${FAITH[@]}" +strategy=pocket
fi

# the run dirs for bench.report, without their maps, pictures and checkpoints (they are rebuilt from nothing here)
tar czf "$OUT/runs.tgz" -C "$RUNS" --exclude='*.ply' --exclude='*.png' --exclude='*.pt' --exclude='maps' \
  --exclude='*.npz' . 2>/dev/null
tar czf "$OUT/profiles.tgz" -C "$OUT" $(cd "$OUT" && ls -d profile_* 2>/dev/null) && rm -rf "$OUT"/profile_*
ls -la "$OUT"
stamp "done"
