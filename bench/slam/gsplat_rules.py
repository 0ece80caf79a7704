"""gsplat's rasterization rules, as the gsplat backend (``raster_gsplat``) and its Triton statistics kernel
(``gsplat_stats``) both apply them; their own module, so neither of the two imports the other for them."""

from __future__ import annotations

import math

TILE_PX = 16  # gsplat's tile_size here: the reference's tile, so tile ids and tiles_xy mean the same
ALPHA_MIN = 1.0 / 255.0  # gsplat's ALPHA_THRESHOLD (Common.h)
GSPLAT_ALPHA_MAX = 0.999  # gsplat's clamp (RasterizeToPixels3DGSFwd.cu)
LOG_T_STOP = math.log(1e-4)  # gsplat stops a pixel before the Gaussian that brings T to 1e-4 or below
