#!/usr/bin/env bash
# Prepare what profiling/gpu_check.sh needs beside the checkout, on the development machine (reports/gpu/README.md):
#   .gpu/whl    gsplat (without glm's doc/ and test/ folders: 20 MB of documentation), pocketbench (for its entry
#               points) and the dependencies the GPU image lacks, as wheels for Python 3.12 on x86-64 Linux
#   .gpu/kitti  KITTI sequence 06 (images, calibration, times) and its poses, from ../shared
#   .gpu/git    a blob-less clone of HEAD, so every run on the GPU records its commit and a clean tree
# and, with --stash / --unstash, moves the largest report folders out of the tree and back, so that what a call
# carries fits its 64 MiB (the runs read no report folder; gpu_check.sh marks them skip-worktree, not changed).
#   bash profiling/gpu_prepare.sh            # build .gpu/ (commit first: .gpu/git is HEAD)
#   bash profiling/gpu_prepare.sh --stash    # before the call;  --unstash after it
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
STASH=${STASH:-/tmp/pocketbench_reports_stash}
BIG=(reports/memory reports/scale reports/real_long)
case "${1:-}" in
  --stash) mkdir -p "$STASH" && for d in "${BIG[@]}"; do mv "$d" "$STASH/"; done; exit 0 ;;
  --unstash) for d in "${BIG[@]}"; do mv "$STASH/$(basename "$d")" reports/; done; exit 0 ;;
  "") ;;
  *) echo "error: expected no argument, --stash or --unstash, found '$1'"; exit 2 ;;
esac
[ -z "$(git status --porcelain --untracked-files=no)" ] || { echo "error: commit first: .gpu/git is HEAD"; exit 2; }
SHARED=${SHARED:-../shared/data/kitti}
rm -rf .gpu/whl .gpu/kitti .gpu/git && mkdir -p .gpu/whl .gpu/kitti/sequences .gpu/kitti/poses
PLAT=(--only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64
      --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)
for p in gsplat==1.5.3 hydra-core==1.3.2 omegaconf==2.3.0 hydra-joblib-launcher==1.2.0 plyfile evo argcomplete \
    natsort numexpr; do
  python3 -m pip download -q --no-deps "${PLAT[@]}" -d .gpu/whl "$p"
done
python3 -m pip download -q --no-deps -d /tmp/antlr antlr4-python3-runtime==4.9.3  # an sdist only: build its wheel
python3 -m pip wheel -q --no-deps -w .gpu/whl /tmp/antlr/antlr4-python3-runtime-4.9.3.tar.gz
python3 -m pip wheel -q --no-deps --no-build-isolation -w .gpu/whl .
tmp=$(mktemp -d)
(cd "$tmp" && unzip -q "$OLDPWD"/.gpu/whl/gsplat-1.5.3-py3-none-any.whl \
  && rm -rf gsplat/cuda/csrc/third_party/glm/doc gsplat/cuda/csrc/third_party/glm/test \
  && grep -v "glm/doc/\|glm/test/" gsplat-1.5.3.dist-info/RECORD >RECORD && mv RECORD gsplat-1.5.3.dist-info/ \
  && rm "$OLDPWD"/.gpu/whl/gsplat-1.5.3-py3-none-any.whl \
  && zip -q -r -9 "$OLDPWD"/.gpu/whl/gsplat-1.5.3-py3-none-any.whl gsplat gsplat-1.5.3.dist-info)
rm -rf "$tmp"
cp -r "$SHARED/sequences/06" .gpu/kitti/sequences/ && cp "$SHARED/poses/06.txt" .gpu/kitti/poses/
git clone -q --bare --depth 1 --filter=blob:none --upload-pack="git -c uploadpack.allowFilter=true upload-pack" \
  "file://$PWD" .gpu/git
du -sh .gpu/*
echo "the tree a call carries: $(git ls-files -co --exclude-standard -z | du -cb --files0-from=- 2>/dev/null | tail -1)"
