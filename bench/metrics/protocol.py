"""Evaluation protocols, named: which pixels of a frame are scored, and with which metrics.

The paper's figures and ours were not measured alike. Its base system, SplaTAM, scores a frame
with the render and the image both multiplied by a mask; the masked pixels are zero in both, so
they count as perfect, while PSNR still divides by every pixel of the image. ``eval.protocol``
picks how a run is scored:

``full``
    The whole image, unmasked: PSNR of the pooled MSE, SSIM (``bench.metrics.image``), MS-SSIM
    and LPIPS. Today's protocol, and the default; its PSNR, SSIM and LPIPS are what runs scored
    before protocols existed.
``splatam``
    SplaTAM's final evaluation (spla-tam/SplaTAM ``utils/eval_helpers.py``, ``eval``, about lines
    467-485): ``valid_depth_mask = (curr_data['depth'] > 0)``, where the dataset loader has
    already set depth outside ``(depth_filter_near, depth_filter_far)`` to 0 (the released
    Pocket-SLAM code, ``datasets/gradslam_datasets/basedataset.py`` about lines 335-338:
    ``mask1 = depth > self.depth_filter_near``, ``mask2 = depth < self.depth_filter_far``,
    ``depth[~mask] = 0.0``; KITTI's range, ``configs/kitti/kitti03.yaml``, is 0.1-30 m). Then
    ``weighted_im = im * valid_depth_mask`` and the same for the image, ``calc_psnr(...).mean()``
    (PSNR per channel over the whole image, averaged: ``psnr_channel_mean_db``),
    ``ms_ssim(..., data_range=1.0, size_average=True)`` and AlexNet LPIPS of the two masked
    images. The range is the dataset's ``eval_depth_near_m`` / ``eval_depth_far_m``.
``released``
    The released Pocket-SLAM code's final evaluation after loop closure
    (UMN-ZhaoLab/Pocket-SLAM ``tools/loop_closure/pose_graph.py``, about lines 620-645, with
    ``sil_thres = 0.5`` at about line 396): ``presence_sil_mask = (silhouette > sil_thres)`` of
    the rendered silhouette, no depth mask, then the same metrics as ``splatam``.

Our SSIM (the module's 11 px Gaussian window) of the masked images is recorded too, beside
MS-SSIM, so a masked run can be set against an unmasked one on each metric. One difference from
the authors' code is kept on purpose: the render is clamped to [0, 1] before every metric (the
authors clamp it for LPIPS only), as the ``full`` protocol always did.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from bench.errors import MetricError
from bench.metrics.image import MS_SSIM_MIN_PX, ms_ssim, psnr_channel_mean_db, psnr_db, ssim

PROTOCOLS: tuple[str, ...] = ("full", "splatam", "released")
MASKED: tuple[str, ...] = ("splatam", "released")  # the protocols the paper's figures can stand beside
RELEASED_SILHOUETTE = 0.5  # pose_graph.py: sil_thres = 0.5; a pixel counts where silhouette > 0.5
FRAME_KEYS: tuple[str, ...] = ("psnr_db", "ssim", "ms_ssim", "lpips", "mask_frac")

Lpips = Callable[[torch.Tensor, torch.Tensor], float]  # bench.metrics.lpips.LPIPS, or any such callable


def _check_protocol(protocol: str) -> None:
    if protocol not in PROTOCOLS:
        raise MetricError(f"eval.protocol: expected one of {', '.join(PROTOCOLS)}, found {protocol!r}")


def protocol_mask(
    protocol: str,
    depth_m: torch.Tensor | None,
    silhouette: torch.Tensor | None,
    depth_near_m: float = 0.0,
    depth_far_m: float | None = None,
) -> torch.Tensor | None:
    """The pixels ``protocol`` scores, ``[H, W]`` bool; None for ``full`` (every pixel).

    ``depth_m`` ``[H, W]``: the frame's observed depth, 0 where the sensor or stereo has none
    (``splatam`` reads it). ``silhouette`` ``[H, W]``: the render's accumulated opacity at the
    evaluated pose (``released`` reads it). ``depth_near_m`` / ``depth_far_m``: the dataset's
    range filter, both ends excluded as in the authors' loader; ``depth_far_m=None`` is no far
    end. A depth of 0 is never valid, whatever the range: it is the loader's "no depth".
    """
    _check_protocol(protocol)
    if protocol == "full":
        return None
    if protocol == "splatam":
        if depth_m is None or depth_m.ndim != 2:
            raise MetricError(
                f"protocol splatam: expected depth [h, w], found {None if depth_m is None else list(depth_m.shape)}"
            )
        if depth_far_m is not None and depth_far_m <= depth_near_m:
            raise MetricError(
                f"protocol splatam: expected depth_near_m < depth_far_m, found {depth_near_m} and {depth_far_m}"
            )
        valid = depth_m > max(depth_near_m, 0.0)  # [H, W]; NaN compares False: invalid
        if depth_far_m is not None:
            valid &= depth_m < depth_far_m
        return valid
    if silhouette is None or silhouette.ndim != 2:
        raise MetricError(
            f"protocol released: expected a silhouette [h, w], found "
            f"{None if silhouette is None else list(silhouette.shape)}"
        )
    return silhouette > RELEASED_SILHOUETTE  # [H, W]


def frame_metrics(
    protocol: str,
    pred: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None,
    lpips: Lpips | None = None,
) -> dict[str, float | None]:
    """One frame scored the way ``protocol`` scores it.

    ``pred`` / ``target`` ``[H, W, 3]`` in [0, 1]; ``mask`` ``[H, W]`` bool from ``protocol_mask``
    (None for ``full``, required otherwise). Returns ``psnr_db``, ``ssim``, ``ms_ssim``, ``lpips``
    (None without a model) and ``mask_frac`` (the share of pixels scored; None for ``full``).
    ``ms_ssim`` is None for images smaller than ``MS_SSIM_MIN_PX`` on a side, which have no fifth
    scale (``ms_ssim`` itself raises there), so small CI runs still score the other metrics.
    """
    _check_protocol(protocol)
    if protocol == "full":
        if mask is not None:
            raise MetricError("protocol full: expected no mask (every pixel counts), found one")
        psnr = psnr_db(pred, target)
        mask_frac = None
    else:
        if mask is None or mask.shape != pred.shape[:2] or mask.dtype != torch.bool:
            found = None if mask is None else f"{mask.dtype} {list(mask.shape)}"
            raise MetricError(f"protocol {protocol}: expected a bool mask of {list(pred.shape[:2])}, found {found}")
        keep = mask[..., None].to(pred.dtype)  # [H, W, 1]
        pred, target = pred * keep, target * keep.to(target.dtype)
        psnr = psnr_channel_mean_db(pred, target)
        mask_frac = float(mask.float().mean())
    return {
        "psnr_db": psnr,
        "ssim": ssim(pred, target),
        "ms_ssim": ms_ssim(pred, target) if min(pred.shape[:2]) >= MS_SSIM_MIN_PX else None,
        "lpips": None if lpips is None else float(lpips(pred, target)),
        "mask_frac": mask_frac,
    }


def mean_metrics(frames: Sequence[dict[str, float | None]]) -> dict[str, float | int | None]:
    """Per-frame metrics averaged over frames, each key over the frames that have it (None where none do).

    PSNR is averaged in dB per frame (the 3DGS and SplaTAM convention), not pooled over MSE; an
    ``inf`` frame makes the mean ``inf``. Sums run in frame order, so the ``full`` protocol's
    PSNR, SSIM and LPIPS equal ``image_metrics``' to the last bit.
    """
    if not frames:
        raise MetricError("no frames to evaluate: expected at least 1, found 0")
    out: dict[str, float | int | None] = {}
    for key in FRAME_KEYS:
        values = [f[key] for f in frames if f.get(key) is not None]
        out[key] = sum(values) / len(values) if values else None  # type: ignore[arg-type]
    out["num_frames"] = len(frames)
    return out


def is_masked(protocol: str | None) -> bool:
    """Whether runs scored with ``protocol`` stand beside the paper's figures (None: a run from before
    protocols, scored ``full``)."""
    return protocol in MASKED
