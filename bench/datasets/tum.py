"""TUM RGB-D: ``<root>/<seq>/{rgb.txt,depth.txt,groundtruth.txt,rgb/,depth/}``.

Each RGB image takes the depth image nearest in time within ``max_diff_s`` (evo's timestamp
matching, as for the ATE); each pair takes the nearest ground-truth pose to its RGB timestamp within
``gt_max_diff_s``. Frames without one are dropped with a log line (``gt_missing: drop``) or
raise (``gt_missing: error``); without a groundtruth.txt has_gt is False. Depth PNGs are 16-bit,
metres = value / ``depth_scale`` (5000), 0 = no reading. Intrinsics come from the config by
the sequence's ``freiburgN`` (TUM's calibrated values); images are used as recorded: the small
fr1/fr2 lens distortion is not undone (fr3 is already undistorted), as in most RGB-D SLAM code.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bench.config.settings import as_config, setting
from bench.datasets import realio
from bench.datasets.base import FrameSequence, RecordedConfig, TimedSequence
from bench.errors import ConfigError, DatasetError
from bench.metrics.timestamp_order import order_problem

LOG = logging.getLogger("bench.datasets.tum")
DATASET = "tum"

# https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats#intrinsic_camera_calibration_of_the_kinect
DEFAULT_INTRINSICS = {
    "fr1": [517.3, 516.5, 318.6, 255.3],
    "fr2": [520.9, 521.0, 325.1, 249.7],
    "fr3": [535.4, 539.2, 320.1, 247.6],
    "default": [525.0, 525.0, 319.5, 239.5],  # ROS default, for sequences not named freiburgN
}


@dataclass
class TumConfig(RecordedConfig, realio.GroundTruthPolicy):
    """``dataset=tum``: TUM RGB-D (see datasets/tum/README.md); depth from the Kinect's 16-bit PNGs."""

    name: str = "tum"
    root: str = "data/tum"  # holds rgbd_dataset_freiburgN_*/
    default_seq: str = "rgbd_dataset_freiburg1_desk"  # folder name, or short form fr1_desk
    downscale: int = 2  # 640x480 -> 320x240; K scaled to match
    max_depth_m: float | None = 10.0  # Kinect readings beyond this are set to 0; None keeps all
    # eval.protocol=splatam keeps the base's range (eval_depth_near_m 0, eval_depth_far_m null: every pixel with
    # depth): SplaTAM's configs/data/TUM/*.yaml set no depth filter, and the released loader filters .npy depth only
    # rgb <-> depth association (TUM associate.py's default tolerance)
    max_diff_s: float = setting(0.02, "float", lo=0.0, lo_open=True)
    depth_scale: float = setting(5000.0, "float", lo=0.0, lo_open=True)  # PNG value per metre
    # [fx, fy, cx, cy] at 640x480, picked by the freiburgN in the sequence name
    intrinsics: dict[str, list[float]] = field(default_factory=lambda: dict(DEFAULT_INTRINSICS))


SCHEMA = TumConfig  # the dataset's typed settings, found through its entry point (bench.datasets.schema)


def resolve_seq(seq: str) -> str:
    """'fr1_desk', 'fr1/desk', 'freiburg1_desk' -> 'rgbd_dataset_freiburg1_desk'; others unchanged."""
    m = re.fullmatch(r"(?:rgbd_dataset_)?(?:fr|freiburg)([123])[_/](.+)", seq)
    return f"rgbd_dataset_freiburg{m.group(1)}_{m.group(2)}" if m else seq


def canonical_seq(seq: Any) -> str:
    """The one name a sequence is recorded under: 'fr1_desk', 'freiburg1_desk' -> 'rgbd_dataset_freiburg1_desk'."""
    return resolve_seq(str(seq).strip())


def camera_key(folder: str) -> str:
    """'fr1' / 'fr2' / 'fr3' from 'rgbd_dataset_freiburgN_...', else 'default'."""
    m = re.search(r"freiburg([123])", folder)
    return f"fr{m.group(1)}" if m else "default"


def read_list(
    path: Path, ncols: int, what: str, numeric: bool = False
) -> tuple[np.ndarray, list[list[str]], list[int]]:
    """A TUM text file -> (timestamps [N] s, other columns per line, line numbers); '#' lines skipped.

    ``numeric`` also requires every other column to be a number (ground truth).
    """
    if not path.is_file():
        raise DatasetError(
            f"tum {what} missing: expected {path}, found {realio.listing(path.parent)} in {path.parent}; "
            f"{realio.readme(DATASET)}"
        )
    stamps, rest, linenos = [], [], []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            if len(parts) != ncols:
                raise ValueError
            stamps.append(float(parts[0]))
            if numeric:
                [float(v) for v in parts[1:]]
        except ValueError:
            raise DatasetError(
                f"tum {what} {path} line {lineno}: expected {ncols} {'numbers' if numeric else 'columns'} "
                f"starting with a timestamp, found {line[:60]!r}"
            ) from None
        rest.append(parts[1:])
        linenos.append(lineno)
    arr = np.array(stamps, dtype=np.float64)
    realio.check_finite_rows(arr[:, None], path, DATASET, what, line_numbers=linenos)
    problem = order_problem(arr, linenos)
    if problem:
        raise DatasetError(f"tum {what} {path} {problem}")
    return arr, rest, linenos


def read_groundtruth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """groundtruth.txt (t tx ty tz qx qy qz qw) -> (timestamps [M] s, c2w [M, 4, 4] float64)."""
    stamps, rest, lines = read_list(path, 8, "ground truth", numeric=True)
    values = np.array(rest, dtype=np.float64).reshape(-1, 7)  # [M, 7]
    realio.check_finite_rows(values, path, DATASET, "ground truth", line_numbers=lines)
    q_wxyz = values[:, [6, 3, 4, 5]]
    return stamps, realio.poses_from_tq(values[:, :3], q_wxyz, path, DATASET)


class TumSequence(TimedSequence):
    """Associated RGB + 16-bit depth frames, read lazily."""

    def __init__(
        self,
        *,
        name: str,
        rgb_paths: list[Path],
        depth_paths: list[Path],
        timestamps_s: np.ndarray,  # [N] of the rgb images
        gt_c2w: np.ndarray | None,  # [N, 4, 4]
        K_full: np.ndarray,  # [3, 3] at full resolution
        full_size: tuple[int, int],  # (width, height)
        downscale: int,
        depth_scale: float,
        max_depth_m: float | None,
    ) -> None:
        super().__init__(name, timestamps_s, gt_c2w)
        self.rgb_paths = rgb_paths
        self.depth_paths = depth_paths
        self.full_width, self.full_height = full_size
        self.downscale = downscale
        self.depth_scale = depth_scale
        self.max_depth_m = max_depth_m
        self.width, self.height = realio.downscaled_size(*full_size, downscale)
        self.K = torch.from_numpy(realio.scale_K(K_full, downscale)).float()

    def depth(self, i: int) -> np.ndarray:
        """Depth [h, w] float32 metres of frame ``i`` (0 = invalid)."""
        path = self.depth_paths[i]
        raw = realio.read_image(path, DATASET, "unchanged")
        if raw.dtype != np.uint16 or raw.ndim != 2:
            chans = 1 if raw.ndim == 2 else raw.shape[2]
            raise DatasetError(
                f"tum depth image {path}: expected a 16-bit single-channel png, found {raw.dtype} with {chans} channels"
            )
        realio.check_size(raw, path, self.full_width, self.full_height, DATASET)
        depth = raw.astype(np.float32) / self.depth_scale  # [H, W]
        if self.max_depth_m is not None:
            depth[depth > self.max_depth_m] = 0.0
        return realio.downscale_depth(depth, self.downscale)

    def load(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        rgb = realio.read_image(self.rgb_paths[i], DATASET, "color")
        realio.check_size(rgb, self.rgb_paths[i], self.full_width, self.full_height, DATASET)
        return realio.rgb_tensor(rgb, self.downscale), torch.from_numpy(self.depth(i))


def _intrinsics(cfg: TumConfig, folder: str) -> np.ndarray:
    table = {**DEFAULT_INTRINSICS, **cfg.intrinsics}
    key = camera_key(folder)
    values = table.get(key, table["default"])
    try:
        fx, fy, cx, cy = (float(v) for v in values)
    except (TypeError, ValueError):
        raise ConfigError(f"tum intrinsics.{key}: expected [fx, fy, cx, cy], found {values!r}") from None
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def open_sequence(cfg: TumConfig | Mapping[str, Any]) -> FrameSequence:
    """Open TUM RGB-D sequence ``cfg.seq`` (folder name or 'fr1_desk'; every setting: ``TumConfig``)."""
    cfg = as_config(TumConfig, cfg)
    requested = cfg.default_sequence()
    root = realio.resolve_root(DATASET, cfg.root)
    folder = requested if (root / requested).is_dir() else resolve_seq(requested)
    seq_dir = root / folder
    if not (seq_dir / "rgb.txt").is_file():
        where = seq_dir if seq_dir.is_dir() else root
        raise DatasetError(
            f"tum sequence '{requested}' not found: expected {seq_dir}/rgb.txt; {where} has: "
            f"{realio.listing(where)}; {realio.readme(DATASET)}"
        )
    rgb_s, rgb_rest, _ = read_list(seq_dir / "rgb.txt", 2, "rgb list")
    depth_s, depth_rest, _ = read_list(seq_dir / "depth.txt", 2, "depth list")
    max_diff_s = cfg.max_diff_s
    depth_of = realio.associate_nearest(rgb_s, depth_s, max_diff_s)  # [N] index into depth, -1 = none
    pairs = [(i, int(j)) for i, j in enumerate(depth_of) if j >= 0]
    if not pairs:
        raise DatasetError(
            f"tum sequence '{folder}': expected rgb and depth timestamps within {max_diff_s} s, found "
            f"{len(rgb_s)} rgb and {len(depth_s)} depth images and no pair"
        )
    LOG.info(
        "tum %s: %d rgb-depth pairs from %d rgb and %d depth images",
        folder,
        len(pairs),
        len(rgb_s),
        len(depth_s),
    )
    ia = np.array([p[0] for p in pairs])
    ib = np.array([p[1] for p in pairs])
    times_s = rgb_s[ia]
    rgb_paths = [seq_dir / rgb_rest[i][0] for i in ia]
    depth_paths = [seq_dir / depth_rest[i][0] for i in ib]

    gt_path = seq_dir / "groundtruth.txt"
    gt = None
    if gt_path.is_file():
        gt_s, T_w_c = read_groundtruth(gt_path)
        assoc = realio.associate_nearest(times_s, gt_s, cfg.gt_max_diff_s)
        keep = realio.apply_gt_policy(assoc, times_s, cfg, DATASET, gt_path, LOG)
        gt = T_w_c[assoc[keep]]
        times_s = times_s[keep]
        rgb_paths = [p for p, k in zip(rgb_paths, keep, strict=True) if k]
        depth_paths = [p for p, k in zip(depth_paths, keep, strict=True) if k]
    else:
        LOG.info("tum %s: no ground truth at %s; has_gt is False", folder, gt_path)

    first = realio.read_image(rgb_paths[0], DATASET, "color")
    height, width = first.shape[:2]
    idx = realio.select(len(rgb_paths), cfg, LOG)
    sequence = TumSequence(
        name=f"tum/{folder}",
        rgb_paths=[rgb_paths[i] for i in idx],
        depth_paths=[depth_paths[i] for i in idx],
        timestamps_s=times_s[idx],
        gt_c2w=None if gt is None else gt[idx],
        K_full=_intrinsics(cfg, folder),
        full_size=(width, height),
        downscale=cfg.downscale,
        depth_scale=cfg.depth_scale,
        max_depth_m=cfg.max_depth_m,
    )
    texts = [seq_dir / "rgb.txt", seq_dir / "depth.txt"] + ([gt_path] if gt is not None else [])
    sequence.source_files = (*texts, *sequence.rgb_paths, *sequence.depth_paths)
    return sequence
