"""KITTI odometry: ``<root>/sequences/XX/{image_0..3,calib.txt,times.txt}`` + ``<root>/poses/XX.txt``.

The left camera of the chosen pair is the SLAM camera (``image_2`` colour or ``image_0`` gray,
``color: auto|color|gray``, falling back with a log line). Depth comes from its stereo partner
(``bench.datasets.stereo``). Ground truth (camera 0 to world) is re-expressed as the c2w of the
camera actually used: each rectified KITTI camera is translated from camera 0 by -K^-1 P[:, 3]
(for P0 that is zero, for P2 about -6 cm along x). Sequences 11-21 have no poses: has_gt False.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.config.settings import as_config, setting
from bench.datasets import realio
from bench.datasets.base import FrameSequence
from bench.datasets.stereo import DepthCache, StereoConfig, StereoSequence
from bench.errors import DatasetError
from bench.metrics.timestamp_order import order_problem

LOG = logging.getLogger("bench.datasets.kitti")
DATASET = "kitti"
_PAIRS = {"color": ("image_2", "image_3", "P2", "P3"), "gray": ("image_0", "image_1", "P0", "P1")}
COLOR_MODES: tuple[str, ...] = ("auto", "color", "gray")


@dataclass
class KittiConfig(StereoConfig):
    """``dataset=kitti``: KITTI odometry (see datasets/kitti/README.md)."""

    name: str = "kitti"
    root: str = "data/kitti"  # holds sequences/XX/ and poses/XX.txt
    default_seq: str = "06"  # numeric names are zero-padded ('6' -> '06')
    # auto | color | gray: image_2/3 (colour) or image_0/1 (gray); falls back with a log line
    color: str = setting("auto", "str", choices=COLOR_MODES)
    downscale: int = 2  # 1241x376 -> 620x188 (1226x370 -> 613x185): a size the fused rasterizer affords on a CPU
    max_depth_m: float | None = 50.0  # stereo depth beyond this is set to 0 (1 px of disparity ~ 8 m at 50 m)
    # eval.protocol=splatam's depth range: the released Pocket-SLAM configs/kitti/kitti03.yaml (and kitti00-02,
    # kitti04-10): depth_filter_near 0.1, depth_filter_far 30.0
    eval_depth_near_m: float = 0.1
    eval_depth_far_m: float | None = 30.0


SCHEMA = KittiConfig  # the dataset's typed settings, found through its entry point (bench.datasets.schema)


def normalize_seq(seq: Any) -> str:
    """'6' / 6 / '06' -> '06'; non-numeric names pass through unchanged."""
    text = str(seq).strip()
    return f"{int(text):02d}" if text.isdigit() else text


def parse_calib(path: Path) -> dict[str, tuple[int, np.ndarray]]:
    """``KEY: v1 v2 ...`` lines -> {key: (line number, values)}; raises on a malformed line."""
    if not path.is_file():
        raise DatasetError(
            f"kitti calib missing: expected {path}, found {realio.listing(path.parent)} in {path.parent}; "
            f"{realio.readme(DATASET)}"
        )
    calib: dict[str, tuple[int, np.ndarray]] = {}
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep or not key.strip() or " " in key.strip():
            raise DatasetError(f"kitti calib {path} line {lineno}: expected 'KEY: numbers', found {line[:40]!r}")
        try:
            values = np.array([float(v) for v in rest.split()], dtype=np.float64)
        except ValueError:
            bad = next(v for v in rest.split() if not _is_float(v))
            raise DatasetError(
                f"kitti calib {path} line {lineno}: expected numbers after '{key.strip()}:', found {bad!r}"
            ) from None
        calib[key.strip()] = (lineno, values)
    return calib


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def projection(calib: dict[str, tuple[int, np.ndarray]], key: str, path: Path, why: str) -> np.ndarray:
    """The [3, 4] projection matrix ``key`` of calib.txt, checked for shape and finiteness."""
    if key not in calib:
        raise DatasetError(f"kitti calib {path}: expected {key} ({why}), found keys {', '.join(calib) or '(none)'}")
    lineno, values = calib[key]
    if values.size != 12 or not np.isfinite(values).all():
        found = f"{values.size} values" if values.size != 12 else "non-finite values"
        raise DatasetError(
            f"kitti calib {path} line {lineno}: expected 12 finite numbers after '{key}:', found {found}"
        )
    P = values.reshape(3, 4)
    if not P[0, 0] > 0 or not P[1, 1] > 0:
        raise DatasetError(
            f"kitti calib {path} line {lineno}: expected positive focal lengths in {key}, found "
            f"fx={P[0, 0]:g} fy={P[1, 1]:g}"
        )
    det = float(np.linalg.det(P[:, :3]))
    if not abs(det) > 1e-9 * abs(P[0, 0] * P[1, 1]):
        raise DatasetError(
            f"kitti calib {path} line {lineno}: expected an invertible left 3x3 block in {key} (K R), "
            f"found a singular one (det {det:g})"
        )
    return P


def canonical_seq(seq: Any) -> str:
    """The one name a sequence is recorded under: '6' / 6 / '06' -> '06'."""
    return normalize_seq(seq)


def camera_offset_m(P: np.ndarray) -> np.ndarray:
    """[3] translation t with x_cam = x_cam0 + t for a rectified KITTI camera: K^-1 P[:, 3]."""
    return np.linalg.solve(P[:, :3], P[:, 3])


def read_times(path: Path) -> np.ndarray:
    """times.txt -> [N] float64 seconds."""
    if not path.is_file():
        raise DatasetError(
            f"kitti times missing: expected {path}, found {realio.listing(path.parent)} in {path.parent}; "
            f"{realio.readme(DATASET)}"
        )
    times, linenos = [], []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        linenos.append(lineno)
        try:
            times.append(float(line))
        except ValueError:
            raise DatasetError(f"kitti times {path} line {lineno}: expected one number, found {line[:40]!r}") from None
    arr = np.array(times, dtype=np.float64)
    realio.check_finite_rows(arr[:, None], path, DATASET, "times")
    problem = order_problem(arr, linenos)
    if problem:
        raise DatasetError(f"kitti times {path} {problem}")
    return arr


def read_poses(path: Path) -> np.ndarray:
    """poses/XX.txt (3x4 row-major camera 0 -> world per line) -> [N, 4, 4] float64."""
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split()
        try:
            values = [float(v) for v in parts]
        except ValueError:
            bad = next(v for v in parts if not _is_float(v))
            raise DatasetError(f"kitti poses {path} line {lineno}: expected 12 numbers, found {bad!r}") from None
        if len(values) != 12:
            raise DatasetError(f"kitti poses {path} line {lineno}: expected 12 numbers, found {len(values)}")
        rows.append(values)
    arr = np.array(rows, dtype=np.float64).reshape(-1, 12)
    realio.check_finite_rows(arr, path, DATASET, "poses")
    T = np.tile(np.eye(4), (len(arr), 1, 1))
    T[:, :3, :] = arr.reshape(-1, 3, 4)
    return T


def _choose_pair(seq_dir: Path, seq: str, mode: str, sequences_dir: Path) -> str:
    """'color' or 'gray' for the requested ``color`` mode, logging the choice and any fallback."""
    have = {k: all((seq_dir / d).is_dir() for d in v[:2]) for k, v in _PAIRS.items()}
    if not any(have.values()):
        if not seq_dir.is_dir():
            raise DatasetError(
                f"kitti sequence '{seq}' not found: expected {seq_dir}/image_2 or image_0; "
                f"{sequences_dir} has: {realio.listing(sequences_dir)}; {realio.readme(DATASET)}"
            )
        raise DatasetError(
            f"kitti sequence '{seq}' has no stereo pair: expected image_2+image_3 or image_0+image_1 in "
            f"{seq_dir}, found: {realio.listing(seq_dir)}; {realio.readme(DATASET)}"
        )
    if mode == "auto":
        pick = "color" if have["color"] else "gray"
        LOG.info("kitti %s: color=auto, using %s images %s/%s", seq, pick, *_PAIRS[pick][:2])
        return pick
    if have[mode]:
        LOG.info("kitti %s: using %s images %s/%s", seq, mode, *_PAIRS[mode][:2])
        return mode
    other = "gray" if mode == "color" else "color"
    LOG.warning(
        "kitti %s: color=%s requested but %s/%s missing in %s; falling back to %s images %s/%s",
        seq,
        mode,
        *_PAIRS[mode][:2],
        seq_dir,
        other,
        *_PAIRS[other][:2],
    )
    return other


def _list_pngs(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")


def open_sequence(cfg: KittiConfig | Mapping[str, Any]) -> FrameSequence:
    """Open KITTI odometry sequence ``cfg.seq`` (every setting: ``KittiConfig``)."""
    cfg = as_config(KittiConfig, cfg)
    seq = normalize_seq(cfg.default_sequence())
    root = realio.resolve_root(DATASET, cfg.root)
    sequences_dir = root / "sequences"
    if not sequences_dir.is_dir():
        raise DatasetError(
            f"kitti sequences folder not found: expected {sequences_dir}; {root} has: {realio.listing(root)}; "
            f"{realio.readme(DATASET)}"
        )
    seq_dir = sequences_dir / seq
    pair = _choose_pair(seq_dir, seq, cfg.color, sequences_dir)
    left_dir, right_dir, left_key, right_key = _PAIRS[pair]

    calib_path = seq_dir / "calib.txt"
    calib = parse_calib(calib_path)
    why = f"projection of {left_dir}/{right_dir}"
    P_left = projection(calib, left_key, calib_path, why)
    P_right = projection(calib, right_key, calib_path, why)
    t_left = camera_offset_m(P_left)  # [3] x_left = x_cam0 + t_left
    baseline_m = float(t_left[0] - camera_offset_m(P_right)[0])
    if not baseline_m > 0:
        raise DatasetError(
            f"kitti calib {calib_path}: expected {right_key} to the right of {left_key} (baseline > 0), "
            f"found baseline {baseline_m:g} m"
        )

    left_paths = _list_pngs(seq_dir / left_dir)
    right_paths = _list_pngs(seq_dir / right_dir)
    n = len(left_paths)
    if n == 0:
        raise DatasetError(f"kitti sequence '{seq}': expected png images in {seq_dir / left_dir}, found none")
    if len(right_paths) != n or [p.name for p in right_paths] != [p.name for p in left_paths]:
        raise DatasetError(
            f"kitti sequence '{seq}': expected matching images in {left_dir} and {right_dir}, "
            f"found {n} and {len(right_paths)}"
        )
    times_path = seq_dir / "times.txt"
    times_s = read_times(times_path)
    if len(times_s) != n:
        raise DatasetError(
            f"kitti times {times_path}: expected {n} lines (one per image in {left_dir}), found {len(times_s)}"
        )

    poses_path = root / "poses" / f"{seq}.txt"
    gt = None
    if poses_path.is_file():
        T_w_c0 = read_poses(poses_path)  # [N, 4, 4]
        if len(T_w_c0) != n:
            raise DatasetError(
                f"kitti poses {poses_path}: expected {n} poses (one per image in {left_dir}), found {len(T_w_c0)}"
            )
        T_c0_cam = np.eye(4)
        T_c0_cam[:3, 3] = -t_left  # centre of the used camera in camera-0 coordinates
        gt = T_w_c0 @ T_c0_cam
    else:
        LOG.info("kitti %s: no ground truth at %s; has_gt is False", seq, poses_path)

    first_img = realio.read_image(left_paths[0], DATASET, "gray")
    height, width = first_img.shape[:2]
    idx = realio.select(n, cfg, LOG)
    sequence = StereoSequence(
        dataset=DATASET,
        name=f"kitti/{seq}",
        left_paths=[left_paths[i] for i in idx],
        right_paths=[right_paths[i] for i in idx],
        timestamps_s=times_s[idx],
        gt_c2w=None if gt is None else gt[idx],
        K_full=P_left[:, :3],
        baseline_m=baseline_m,
        full_size=(width, height),
        colour=pair == "color",
        downscale=cfg.downscale,
        params=cfg.stereo,
        max_depth_m=cfg.max_depth_m,
        cache=DepthCache(cfg.cache_dir, DATASET),
    )
    texts = [calib_path, times_path] + ([poses_path] if gt is not None else [])
    sequence.source_files = (*texts, *sequence.left_paths, *sequence.right_paths)
    return sequence
