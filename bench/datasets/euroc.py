"""EuRoC MAV (ASL layout): ``<root>/<seq>/mav0/{cam0,cam1,state_groundtruth_estimate0}``.

The raw images are distorted (radial-tangential) and unrectified, so the pair is rectified with
``cv2.stereoRectify`` from both ``sensor.yaml`` files (intrinsics, distortion, T_BS); the SLAM
camera is the *rectified* cam0, with K = P1[:3, :3]. Ground truth (body/IMU frame, Vicon or
Leica) becomes that camera's c2w: T_W_Crect = T_W_B @ T_BS(cam0) @ [R1^T | 0].

Frames without a ground-truth pose within ``gt_max_diff_s`` are dropped with a log line
(``gt_missing: drop``, default: the real ground truth can start after the cameras) or raise
(``gt_missing: error``); either way has_gt is True and every frame carries a pose. Without a
``state_groundtruth_estimate0/data.csv`` at all, has_gt is False.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from bench.config.settings import as_config, setting
from bench.datasets import realio
from bench.datasets.base import FrameSequence
from bench.datasets.stereo import DepthCache, StereoConfig, StereoParams, StereoSequence
from bench.errors import DatasetError
from bench.metrics.timestamp_order import order_problem

LOG = logging.getLogger("bench.datasets.euroc")
DATASET = "euroc"

ALIASES = {
    "MH01": "MH_01_easy",
    "MH02": "MH_02_easy",
    "MH03": "MH_03_medium",
    "MH04": "MH_04_difficult",
    "MH05": "MH_05_difficult",
    "V101": "V1_01_easy",
    "V102": "V1_02_medium",
    "V103": "V1_03_difficult",
    "V201": "V2_01_easy",
    "V202": "V2_02_medium",
    "V203": "V2_03_difficult",
}


@dataclass
class EurocConfig(StereoConfig, realio.GroundTruthPolicy):
    """``dataset=euroc``: EuRoC MAV, ASL layout (see datasets/euroc/README.md)."""

    name: str = "euroc"
    root: str = "data/euroc"  # holds <seq>/mav0/
    default_seq: str = "V1_01_easy"  # folder name or alias: MH01..MH05, V101..V103, V201..V203
    downscale: int = 2  # 752x480 -> 376x240; K (rectified P1) scaled to match
    max_depth_m: float | None = 10.0  # 0.11 m baseline: 1 px of disparity ~ 2 m at 10 m
    # eval.protocol=splatam's depth range: the released Pocket-SLAM configs/euroc/euroc.yaml
    # (depth_filter_near 0.1, depth_filter_far 10.0)
    eval_depth_near_m: float = 0.1
    eval_depth_far_m: float | None = 10.0
    # cv2.stereoRectify alpha: 0 crops to valid pixels, 1 keeps all (black borders)
    rectify_alpha: float = setting(0.0, "float", lo=0.0, hi=1.0)
    # nearest depth fx*b/64 ~ 0.75 m at full resolution
    stereo: StereoParams = field(default_factory=lambda: StereoParams(num_disparities=64))


SCHEMA = EurocConfig  # the dataset's typed settings, found through its entry point (bench.datasets.schema)


def resolve_seq(seq: str) -> str:
    """Folder name for ``seq``: 'MH01', 'mh_01', 'V101' -> official names; others unchanged."""
    key = re.sub(r"[^A-Za-z0-9]", "", seq).upper()
    return ALIASES.get(key, seq)


def canonical_seq(seq: Any) -> str:
    """The one name a sequence is recorded under: 'V101', 'v1_01', 'V1_01_easy' -> 'V1_01_easy'."""
    return resolve_seq(str(seq).strip())


def read_sensor_yaml(path: Path) -> dict[str, Any]:
    """cam sensor.yaml -> {K [3,3], dist [4], T_BS [4,4], size (w, h)}; the %YAML header is stripped."""
    if not path.is_file():
        raise DatasetError(
            f"euroc sensor.yaml missing: expected {path}, found {realio.listing(path.parent)} in {path.parent}; "
            f"{realio.readme(DATASET)}"
        )
    text = "\n".join(line for line in path.read_text().splitlines() if not line.startswith("%YAML"))
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 2}" if mark is not None else ""  # +1 for 1-based, +1 for the header
        problem = str(getattr(exc, "problem", None) or "invalid yaml").replace("\n", " ")
        raise DatasetError(f"euroc sensor.yaml {path}{where}: expected valid yaml, found {problem}") from None
    if not isinstance(data, dict):
        raise DatasetError(f"euroc sensor.yaml {path}: expected a mapping of keys, found {type(data).__name__}")

    def numbers(key: str, n: int, value: Any = None) -> np.ndarray:
        value = data.get(key) if value is None else value
        if value is None:
            raise DatasetError(
                f"euroc sensor.yaml {path}: expected key '{key}', found keys {', '.join(map(str, data))}"
            )
        try:
            arr = np.asarray(value, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise DatasetError(f"euroc sensor.yaml {path} key '{key}': expected {n} numbers, found {value!r}") from None
        if arr.size != n or not np.isfinite(arr).all():
            raise DatasetError(
                f"euroc sensor.yaml {path} key '{key}': expected {n} finite numbers, found {arr.size}: "
                f"{np.array2string(arr, separator=',', max_line_width=10_000)}"
            )
        return arr

    model = data.get("distortion_model")
    if model not in ("radial-tangential", "radtan"):
        raise DatasetError(
            f"euroc sensor.yaml {path} key 'distortion_model': expected radial-tangential, found {model!r}"
        )
    if data.get("camera_model", "pinhole") != "pinhole":
        raise DatasetError(
            f"euroc sensor.yaml {path} key 'camera_model': expected pinhole, found {data.get('camera_model')!r}"
        )
    t_bs = data.get("T_BS")
    if not isinstance(t_bs, dict):
        raise DatasetError(f"euroc sensor.yaml {path} key 'T_BS': expected a mapping with 'data', found {t_bs!r}")
    T_BS = numbers("T_BS.data", 16, t_bs.get("data", [])).reshape(4, 4)
    if not np.allclose(T_BS[:3, :3] @ T_BS[:3, :3].T, np.eye(3), atol=1e-4):
        raise DatasetError(f"euroc sensor.yaml {path} key 'T_BS': expected a rigid transform, found a non-rotation")
    fu, fv, cu, cv = numbers("intrinsics", 4)
    if not (fu > 0 and fv > 0):
        raise DatasetError(
            f"euroc sensor.yaml {path} key 'intrinsics': expected positive focal lengths fu, fv, found {fu:g}, {fv:g}"
        )
    res = numbers("resolution", 2)
    if not (res > 0).all() or not np.allclose(res, np.round(res)):
        raise DatasetError(
            f"euroc sensor.yaml {path} key 'resolution': expected positive integer width and height, "
            f"found {res.tolist()}"
        )
    w, h = res.astype(int)
    if not (0 <= cu < w and 0 <= cv < h):
        raise DatasetError(
            f"euroc sensor.yaml {path} key 'intrinsics': expected the principal point inside the {w}x{h} image, "
            f"found cu={cu:g} cv={cv:g}"
        )
    return {
        "K": np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]]),
        "dist": numbers("distortion_coefficients", 4),
        "T_BS": T_BS,
        "size": (int(w), int(h)),
    }


def read_cam_csv(cam_dir: Path) -> tuple[np.ndarray, list[str]]:
    """cam data.csv -> (timestamps [N] int64 ns, file names); checks it against data/."""
    path = cam_dir / "data.csv"
    if not path.is_file():
        raise DatasetError(f"euroc camera list missing: expected {path}, found {realio.listing(cam_dir)} in {cam_dir}")
    stamps, names, linenos = [], [], []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        if len(parts) != 2 or not parts[0].isdigit():
            raise DatasetError(
                f"euroc camera list {path} line {lineno}: expected 'timestamp_ns,filename', found {line[:60]!r}"
            )
        stamps.append(int(parts[0]))
        names.append(parts[1])
        linenos.append(lineno)
    _check_order(stamps, linenos, path, "camera list")
    n_files = sum(1 for p in (cam_dir / "data").glob("*.png")) if (cam_dir / "data").is_dir() else 0
    if n_files != len(names):
        raise DatasetError(
            f"euroc camera list {path}: expected one png in {cam_dir / 'data'} per line ({len(names)}), found {n_files}"
        )
    return np.array(stamps, dtype=np.int64), names


def _check_order(stamps_ns: list[int], linenos: list[int], path: Path, what: str) -> None:
    """Strictly increasing timestamps, or one ``DatasetError`` line naming the row."""
    problem = order_problem(np.array(stamps_ns, dtype=np.int64) * 1e-9, linenos)
    if problem:
        raise DatasetError(f"euroc {what} {path} {problem}")


def read_groundtruth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """state_groundtruth_estimate0/data.csv -> (timestamps [M] int64 ns, T_W_B [M, 4, 4])."""
    stamps, rows, linenos = [], [], []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split(",")
        try:
            stamp = int(parts[0])
            values = [float(v) for v in parts[1:8]]
        except ValueError:
            raise DatasetError(
                f"euroc ground truth {path} line {lineno}: expected 'timestamp_ns,px,py,pz,qw,qx,qy,qz,...', "
                f"found {line[:60]!r}"
            ) from None
        if len(values) != 7:
            raise DatasetError(
                f"euroc ground truth {path} line {lineno}: expected at least 8 comma-separated values, "
                f"found {len(parts)}"
            )
        stamps.append(stamp)
        rows.append(values)
        linenos.append(lineno)
    arr = np.array(rows, dtype=np.float64).reshape(-1, 7)
    realio.check_finite_rows(arr, path, DATASET, "ground truth", line_numbers=linenos)
    _check_order(stamps, linenos, path, "ground truth")
    return np.array(stamps, dtype=np.int64), realio.poses_from_tq(arr[:, :3], arr[:, 3:7], path, DATASET)


def rectification(cam0: dict[str, Any], cam1: dict[str, Any], alpha: float) -> dict[str, np.ndarray]:
    """stereoRectify for the pair: R1/R2 [3,3], P1/P2 [3,4] and the undistort+rectify maps."""
    T_c1_c0 = np.linalg.inv(cam1["T_BS"]) @ cam0["T_BS"]  # cam0 coords -> cam1 coords
    size = cam0["size"]
    R1, R2, P1, P2, _Q, _roi1, _roi2 = cv2.stereoRectify(
        cam0["K"],
        cam0["dist"],
        cam1["K"],
        cam1["dist"],
        size,
        T_c1_c0[:3, :3],
        T_c1_c0[:3, 3].reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=alpha,
    )
    maps = [
        cv2.initUndistortRectifyMap(cam["K"], cam["dist"], R, P, size, cv2.CV_32FC1)
        for cam, R, P in ((cam0, R1, P1), (cam1, R2, P2))
    ]
    return {"R1": R1, "R2": R2, "P1": P1, "P2": P2, "maps": maps}


def open_sequence(cfg: EurocConfig | Mapping[str, Any]) -> FrameSequence:
    """Open EuRoC sequence ``cfg.seq`` (folder name or alias; every setting: ``EurocConfig``)."""
    cfg = as_config(EurocConfig, cfg)
    requested = cfg.default_sequence()
    root = realio.resolve_root(DATASET, cfg.root)
    folder = requested if (root / requested).is_dir() else resolve_seq(requested)
    mav = root / folder / "mav0"
    if not (mav / "cam0").is_dir() or not (mav / "cam1").is_dir():
        alias = f" (alias of {folder})" if folder != requested else ""
        where = mav if (root / folder).is_dir() else root
        raise DatasetError(
            f"euroc sequence '{requested}'{alias} not found: expected {mav}/cam0 and cam1; "
            f"{where} has: {realio.listing(where)}; {realio.readme(DATASET)}"
        )

    cam0 = read_sensor_yaml(mav / "cam0" / "sensor.yaml")
    cam1 = read_sensor_yaml(mav / "cam1" / "sensor.yaml")
    if cam0["size"] != cam1["size"]:
        raise DatasetError(
            f"euroc sensor.yaml {mav / 'cam1' / 'sensor.yaml'} key 'resolution': "
            f"expected {list(cam0['size'])} like cam0, found {list(cam1['size'])}"
        )
    stamps0, names0 = read_cam_csv(mav / "cam0")
    stamps1, names1 = read_cam_csv(mav / "cam1")
    # EuRoC triggers both cameras together: pair frames by identical timestamps.
    right_of = {s: n for s, n in zip(stamps1.tolist(), names1, strict=True)}
    pairs = [(s, n, right_of[s]) for s, n in zip(stamps0.tolist(), names0, strict=True) if s in right_of]
    if not pairs:
        raise DatasetError(
            f"euroc sequence '{requested}': expected cam0 and cam1 frames with equal timestamps, found "
            f"{len(stamps0)} cam0 and {len(stamps1)} cam1 frames and no common timestamp"
        )
    if len(pairs) < len(stamps0):
        LOG.warning("euroc %s: %d cam0 frames have no cam1 partner; dropped", folder, len(stamps0) - len(pairs))
    stamps_ns = np.array([p[0] for p in pairs], dtype=np.int64)
    left_paths = [mav / "cam0" / "data" / p[1] for p in pairs]
    right_paths = [mav / "cam1" / "data" / p[2] for p in pairs]

    alpha = cfg.rectify_alpha
    rect = rectification(cam0, cam1, alpha)
    P1, P2 = rect["P1"], rect["P2"]
    baseline_m = float(-P2[0, 3] / P2[0, 0])
    if not baseline_m > 0:
        raise DatasetError(
            f"euroc sensor.yaml T_BS: expected cam1 to the right of cam0 after rectification, "
            f"found baseline {baseline_m:g} m"
        )

    gt_path = mav / "state_groundtruth_estimate0" / "data.csv"
    gt = None
    if gt_path.is_file():
        gt_ns, T_W_B = read_groundtruth(gt_path)
        max_diff_s = cfg.gt_max_diff_s
        # associate in int64 ns relative to the first frame: float64 seconds since 1970 lose ~0.2 us
        assoc = realio.associate_nearest((stamps_ns - stamps_ns[0]) * 1e-9, (gt_ns - stamps_ns[0]) * 1e-9, max_diff_s)
        keep = realio.apply_gt_policy(assoc, stamps_ns * 1e-9, cfg, DATASET, gt_path, LOG)
        T_C0_Crect = np.eye(4)
        T_C0_Crect[:3, :3] = rect["R1"].T  # x_rect = R1 @ x_cam0
        gt = T_W_B[assoc[keep]] @ cam0["T_BS"] @ T_C0_Crect
        stamps_ns = stamps_ns[keep]
        left_paths = [p for p, k in zip(left_paths, keep, strict=True) if k]
        right_paths = [p for p, k in zip(right_paths, keep, strict=True) if k]
    else:
        LOG.info("euroc %s: no ground truth at %s; has_gt is False", folder, gt_path)

    idx = realio.select(len(left_paths), cfg, LOG)
    maps = rect["maps"]

    def rectify(img: np.ndarray, side: int) -> np.ndarray:
        return cv2.remap(img, maps[side][0], maps[side][1], cv2.INTER_LINEAR)

    sequence = StereoSequence(
        dataset=DATASET,
        name=f"euroc/{folder}",
        left_paths=[left_paths[i] for i in idx],
        right_paths=[right_paths[i] for i in idx],
        timestamps_s=stamps_ns[idx] * 1e-9,
        gt_c2w=None if gt is None else gt[idx],
        K_full=P1[:3, :3],
        baseline_m=baseline_m,
        full_size=cam0["size"],  # stereoRectify keeps the image size
        raw_size=cam0["size"],
        colour=False,
        downscale=cfg.downscale,
        params=cfg.stereo,
        max_depth_m=cfg.max_depth_m,
        cache=DepthCache(cfg.cache_dir, DATASET),
        rectify=rectify,
        key_extra={
            "rectify": {
                "alpha": alpha,
                "P1": np.round(P1, 9).tolist(),
                "P2": np.round(P2, 9).tolist(),
                "R1": np.round(rect["R1"], 12).tolist(),
                "R2": np.round(rect["R2"], 12).tolist(),
                "dist0": cam0["dist"].tolist(),
                "dist1": cam1["dist"].tolist(),
                "K0": cam0["K"].tolist(),
                "K1": cam1["K"].tolist(),
            }
        },
    )
    texts = [mav / c / n for c in ("cam0", "cam1") for n in ("sensor.yaml", "data.csv")]
    texts += [gt_path] if gt is not None else []
    sequence.source_files = (*texts, *sequence.left_paths, *sequence.right_paths)
    return sequence
