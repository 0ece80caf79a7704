"""The ``fused`` rasterizer backend: compiled CPU kernels for binning, compositing and its gradient.

The torch backend pads every tile's list into dense ``[tiles, 256, K]`` blocks that autograd keeps
for the backward pass, so its memory follows the tile overlaps of the largest Gaussians rather than
the number of Gaussians. This backend keeps what the CUDA rasterizer of 3DGS keeps: the
(tile, Gaussian) list sorted by tile then depth, each Gaussian's projected quantities, and per pixel
the final transmittance and the index of its last contributor. The backward pass walks each
pixel's contributors back to front and recomputes the rest.

Design choices, and why:
- Gaussian-major loops inside a tile: the depth-sorted list is walked once and each Gaussian visits
  only the pixels of its exact 1/255 bounding box (the ellipse where ``o exp(-d^T S^-1 d / 2)``
  reaches 1/255), so the cost is the sum of box areas, not pixels x list length. Per-pixel
  compositing order is still front to back because the list is depth-sorted.
- Vectorised pixels: a Gaussian updates its box 8 or 16 pixels (one AVX2 or AVX-512 register, as
  LLVM picks for the host) at a time, with masks instead of branches, so a pixel outside the
  ellipse costs a lane rather than a mispredicted branch. How the loops are written so that LLVM
  vectorises them is said where the tile state is laid out (``S_X``); check it in the assembly
  (ymm or zmm registers) after a change.
- Work per Gaussian in view: the projection runs over the whole map, but a Gaussian culled by its
  centre costs a few operations there, and everything after it (``raster._render_fused``) runs on
  the Gaussians with a tile. The backward walks a tile's list only down from the last contributor
  of a pixel that a gradient reaches (tracking masks most of the sky and unmapped street).
- Determinism: tiles run in parallel but each writes only its own pixels and its own slice of the
  pair list. Per-Gaussian sums (gradients, pruning statistics) are first written per pair, then
  reduced over pairs in list order by one sequential loop. The result does not depend on the
  thread count or the schedule: bit-identical from run to run.
- Tiles are dealt to threads by their pair count (largest first, round robin) rather than split
  into contiguous halves of the image, so that a thread given the sky does not wait for the one
  given the road. Which thread runs a tile changes nothing in its result.
- Every buffer the kernels fill is a torch tensor (they receive numpy views), so the live-tensor
  memory probe of ``bench/measure/memory.py`` counts it. Only each thread's tile state (10-15 floats per
  pixel of one tile, under 16 KiB) and the kernels' scalars live outside torch.
- float32 throughout, with float32 literals: numba promotes mixed int/float32 arithmetic to float64.
"""

from bench.slam.raster_fused.autograd import composite, project
from bench.slam.raster_fused.binning import bin_pairs, in_view
from bench.slam.raster_fused.warmup import compile_kernels

__all__ = ["bin_pairs", "compile_kernels", "composite", "in_view", "project"]
