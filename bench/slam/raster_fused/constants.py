"""The numeric conventions every kernel shares: tile size, float32, the alpha and transmittance bounds."""

from __future__ import annotations

import numpy as np

TILE = 16
F32 = np.float32
ALPHA_MIN = F32(1.0 / 255.0)
ALPHA_MAX = F32(0.99)
T_MIN = F32(1e-4)
LOWPASS_PX2 = F32(0.3)  # the EWA low-pass every screen covariance holds (raster.LOWPASS_PX2)
# the pruning statistic C_i sums o exp(power) over whole tiles; terms below exp(-20) of the peak are
# dropped, which changes no float32 sum
COVERAGE_POWER_MIN = F32(-20.0)
N_FEAT = 4  # r, g, b, depth
