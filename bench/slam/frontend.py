"""Sparse frame-to-frame motion guess: optical-flow tracks + PnP on the previous frame's depth.

Why: photometric tracking of a forward-driving camera has a long, nearly flat valley along the
optical axis (road and facades are parallel to the motion). A constant-velocity guess a few
centimetres off can land in the wrong minimum, and the error then compounds from frame to
frame until tracking is lost early in a drive (the runs: reports/known_limits.md). Corners tracked
between consecutive frames pin the forward motion independently of the map, so the photometric
refinement starts inside the right basin. The constant-velocity prediction is still where the
search starts: it seeds PnP's refinement, and it is the guess whenever too few corners survive.
OpenCV does the work: Shi-Tomasi corners, pyramidal Lucas-Kanade with a forward-backward check,
and RANSAC PnP.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from bench.config.settings import check_rules, setting


@dataclass
class FlowPnpConfig:
    max_corners: int = setting(600, "int", lo=1)
    # Shi-Tomasi quality level, relative to the strongest corner
    quality: float = setting(0.01, "float", lo=0.0, hi=1.0, lo_open=True)
    min_distance_px: int = setting(3, "int", lo=0)
    window_px: int = setting(15, "int", lo=3)  # Lucas-Kanade window
    levels: int = setting(3, "int", lo=0)  # Lucas-Kanade pyramid levels
    # forward-backward disagreement beyond this drops a track
    fb_max_px: float = setting(1.0, "float", lo=0.0, lo_open=True)
    # far points carry little translation information and noisy depth
    max_depth_m: float = setting(40.0, "float", lo=0.0, lo_open=True)
    reproj_px: float = setting(1.0, "float", lo=0.0, lo_open=True)  # RANSAC inlier threshold
    min_inliers: int = setting(30, "int", lo=4)  # fewer: no guess (the caller falls back to constant velocity)

    def __post_init__(self) -> None:
        check_rules(self, "slam.flow_pnp.")


def to_gray_u8(rgb: torch.Tensor) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> [H, W] uint8."""
    return (rgb.detach().float().mean(-1).clamp(0, 1) * 255).to(torch.uint8).cpu().numpy()


def relative_motion(
    prev_gray: np.ndarray,  # [H, W] uint8
    cur_gray: np.ndarray,  # [H, W] uint8
    prev_depth_m: np.ndarray,  # [H, W] float, 0 where invalid
    K: np.ndarray,  # [3, 3]
    cfg: FlowPnpConfig,
    prior: np.ndarray | None = None,  # [4, 4] previous -> current camera, e.g. constant velocity
    rng: np.random.Generator | None = None,
    inliers_out: list | None = None,
) -> tuple[np.ndarray | None, int]:
    """Transform from the previous camera frame to the current one ([4, 4]), and the inlier count.

    ``inliers_out``, when given, receives the RANSAC inliers of an accepted guess as two arrays: their
    points in the previous camera's frame [M, 3] (m) and where they were tracked to in the current image
    [M, 2] (px); the tracking loss can keep them in view (``slam.feature_weight``).

    ``prior`` seeds the iterative PnP (RANSAC still picks the inliers). Returns ``(None, n)`` when
    there are too few reliable tracks to trust a guess. ``rng`` shuffles the correspondences
    before RANSAC: OpenCV's RANSAC draws its samples from a private generator with a fixed seed
    (``cv2.setRNGSeed`` does not reach it), so the order of the points is what a seed can vary.
    """
    p0 = cv2.goodFeaturesToTrack(prev_gray, cfg.max_corners, cfg.quality, cfg.min_distance_px)
    if p0 is None or len(p0) < cfg.min_inliers:
        return None, 0
    lk = dict(winSize=(cfg.window_px, cfg.window_px), maxLevel=cfg.levels)
    # cv2's stub types nextPts as a required array; None (OpenCV allocates the output) is what its docs show
    p1, st, _ = cv2.calcOpticalFlowPyrLK(prev_gray, cur_gray, p0, None, **lk)  # type: ignore[call-overload]
    pb, st_b, _ = cv2.calcOpticalFlowPyrLK(cur_gray, prev_gray, p1, None, **lk)  # type: ignore[call-overload]
    ok = (st[:, 0] == 1) & (st_b[:, 0] == 1) & (np.linalg.norm(pb - p0, axis=-1)[:, 0] < cfg.fb_max_px)
    p0, p1 = p0[ok, 0].astype(np.float64), p1[ok, 0].astype(np.float64)  # [M, 2]
    h, w = prev_depth_m.shape
    u = np.clip(np.round(p0[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.round(p0[:, 1]).astype(int), 0, h - 1)
    z = prev_depth_m[v, u].astype(np.float64)
    good = (z > 0) & (z < cfg.max_depth_m)
    if good.sum() < cfg.min_inliers:
        return None, int(good.sum())
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    pts = np.stack([(p0[good, 0] - cx) / fx * z[good], (p0[good, 1] - cy) / fy * z[good], z[good]], -1)  # [M, 3]
    uv = p1[good]  # [M, 2]
    if rng is not None:
        perm = rng.permutation(len(pts))
        pts, uv = pts[perm], uv[perm]
    rvec0 = tvec0 = None
    if prior is not None and np.isfinite(prior).all():
        rvec0, tvec0 = cv2.Rodrigues(prior[:3, :3].astype(np.float64))[0], prior[:3, 3:4].astype(np.float64).copy()
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        pts,
        uv,
        K.astype(np.float64),
        None,
        rvec=rvec0,
        tvec=tvec0,
        useExtrinsicGuess=rvec0 is not None,
        reprojectionError=cfg.reproj_px,
        iterationsCount=200,
        flags=cv2.SOLVEPNP_ITERATIVE,
    )
    n_in = 0 if inliers is None else len(inliers)
    if not found or n_in < cfg.min_inliers or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        return None, n_in
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec[:, 0]
    if inliers_out is not None:
        idx = inliers[:, 0]
        inliers_out.extend([pts[idx], uv[idx]])
    return T, n_in
