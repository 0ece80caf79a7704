"""Evaluation metrics: trajectory accuracy (evo), image quality (torchmetrics), LPIPS (local weights),
and the evaluation protocols that decide which pixels count (``bench.metrics.protocol``)."""

from bench.metrics.image import image_metrics, ms_ssim, psnr_db, ssim
from bench.metrics.lpips import LPIPS
from bench.metrics.protocol import PROTOCOLS, frame_metrics, mean_metrics, protocol_mask
from bench.metrics.trajectory import Trajectory, ate, path_length_ratio, read_tum, rpe, write_tum

__all__ = [
    "LPIPS",
    "PROTOCOLS",
    "Trajectory",
    "ate",
    "frame_metrics",
    "image_metrics",
    "mean_metrics",
    "ms_ssim",
    "path_length_ratio",
    "protocol_mask",
    "psnr_db",
    "read_tum",
    "rpe",
    "ssim",
    "write_tum",
]
