"""When tracking counts as lost: ``LostDetector`` and the state it keeps between frames."""

from __future__ import annotations

import numpy as np

from bench.errors import TrackingLost
from bench.slam.config import SlamConfig

# lost_check=depth judges a frame once this many frames make its baseline: the depth error a map reaches
# depends on the sensor (exact synthetic depth, noisy stereo), so the first frames are the reference
DEPTH_BASELINE_MIN = 3


class LostDetector:
    """What declares tracking lost, with the state it keeps between frames.

    Besides a collapsed silhouette, ``slam.lost_check`` picks the residual that flags a frame: the colour
    L1 on confidently mapped pixels (``color``), the depth L1 on them against a baseline of recent
    unflagged frames (``depth``), either (``both``) or neither (``off``); ``lost_patience`` consecutive
    flagged frames end the run (``TrackingLost``). Why both readings exist: see ``SlamConfig.lost_check``.
    """

    def __init__(self, cfg: SlamConfig) -> None:
        self.cfg = cfg
        self.bad_frames = 0  # consecutive flagged frames
        self.depth_recent: list[float] = []  # lost_check=depth: depth L1 of the last unflagged frames (the baseline)

    def depth_threshold_m(self) -> float:
        """The depth L1 (m) above which the next frame counts as bad under ``lost_check=depth``."""
        if len(self.depth_recent) < DEPTH_BASELINE_MIN:  # no reference yet: the first frames set it
            return float("inf")
        return max(self.cfg.lost_depth_floor_m, self.cfg.lost_depth_ratio * float(np.median(self.depth_recent)))

    def check(self, frame_index: int, color_l1: float, sil_frac: float, depth_l1: float) -> None:
        """Judge one tracked frame: ``TrackingLost`` when its silhouette collapsed (fewer confident pixels than
        ``lost_min_silhouette_frac``), or at ``lost_patience`` consecutive bad frames under ``lost_check``."""
        cfg = self.cfg
        if sil_frac < cfg.lost_min_silhouette_frac:
            raise TrackingLost(
                f"tracking lost at frame {frame_index}: silhouette collapsed to {sil_frac:.3f} "
                f"of pixels (expected >= {cfg.lost_min_silhouette_frac})"
            )
        if cfg.lost_check == "off":
            return
        why = []
        if cfg.lost_check in ("depth", "both"):
            threshold = self.depth_threshold_m()
            if depth_l1 > threshold:
                why.append(
                    f"depth residual {depth_l1:.3f} m above {threshold:.3f} m ({cfg.lost_depth_ratio} x recent median)"
                )
            else:  # flagged frames stay out of the baseline, so a loss cannot raise its own bar
                self.depth_recent = (self.depth_recent + [depth_l1])[-cfg.lost_baseline_frames :]
        if cfg.lost_check in ("color", "both") and color_l1 > cfg.lost_residual:
            why.append(f"colour residual {color_l1:.3f} above {cfg.lost_residual}")
        self.bad_frames = self.bad_frames + 1 if why else 0
        if self.bad_frames >= cfg.lost_patience:
            raise TrackingLost(
                f"tracking lost at frame {frame_index}: {' and '.join(why)} for {self.bad_frames} frames"
            )
