"""Evaluation metrics: trajectory accuracy (evo), image quality (torchmetrics), LPIPS (local weights)."""

from bench.metrics.image import image_metrics, psnr_db, ssim
from bench.metrics.lpips import LPIPS
from bench.metrics.trajectory import Trajectory, ate, read_tum, rpe, write_tum

__all__ = ["LPIPS", "Trajectory", "ate", "image_metrics", "psnr_db", "read_tum", "rpe", "ssim", "write_tum"]
