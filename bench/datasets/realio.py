"""Shared plumbing for the real-data loaders (KITTI, EuRoC, TUM).

Kept in one place so every loader reports bad input the same way: one lowercase line, a
``DatasetError`` (or ``ConfigError`` for a bad knob), saying what was expected and what was found.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from evo.core import sync

from bench.config.settings import setting
from bench.datasets.base import RecordedConfig
from bench.errors import ConfigError, DatasetError
from bench.slam.se3 import quat_to_rotmat

REPO = Path(__file__).resolve().parents[2]
_LOG = logging.getLogger("bench.datasets")
GT_POLICIES: tuple[str, ...] = ("drop", "error")


@dataclass
class GroundTruthPolicy:
    """How frames are matched to a ground truth recorded on its own clock (EuRoC, TUM)."""

    # frame <-> ground-truth timestamp association tolerance
    gt_max_diff_s: float = setting(0.02, "float", lo=0.0, lo_open=True)
    # drop | error: what to do with frames that have no pose within gt_max_diff_s
    gt_missing: str = setting("drop", "str", choices=GT_POLICIES)


def readme(dataset: str) -> str:
    return f"see datasets/{dataset}/README.md"


def listing(path: Path, limit: int = 12) -> str:
    """Comma-separated contents of ``path`` for error messages ("(empty)" / "(missing)")."""
    if not path.is_dir():
        return "(missing)"
    names = sorted(p.name for p in path.iterdir() if not p.name.startswith("."))
    if not names:
        return "(empty)"
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def resolve_root(dataset: str, root: Any) -> Path:
    """The dataset root as an absolute path; relative roots are tried against cwd, then the repo."""
    if root is None or str(root).strip() == "":
        raise ConfigError(f"{dataset} root: expected a directory path (dataset.root=...), found none")
    raw = Path(str(root)).expanduser()
    candidates = [raw] if raw.is_absolute() else [Path.cwd() / raw, REPO / raw]
    for cand in candidates:
        if cand.is_dir():
            return cand.resolve()
    tried = " or ".join(str(c) for c in dict.fromkeys(candidates))
    parent = candidates[0].parent
    raise DatasetError(
        f"{dataset} root not found: expected a directory at {tried} (dataset.root={root}); "
        f"found nothing there ({parent} has: {listing(parent)}); {readme(dataset)}"
    )


def read_image(path: Path, dataset: str, mode: str) -> np.ndarray:
    """Read a PNG as uint8 ``gray`` [H, W], uint8 ``color`` BGR [H, W, 3] or raw ``unchanged``."""
    flags = {
        "gray": cv2.IMREAD_GRAYSCALE,
        "color": cv2.IMREAD_COLOR,
        "unchanged": cv2.IMREAD_UNCHANGED,
    }[mode]
    if not path.is_file():
        raise DatasetError(f"{dataset} image missing: expected a file at {path}, found nothing")
    check_image_file(path, dataset, 8 if mode != "unchanged" else None)
    img = cv2.imread(str(path), flags)
    if img is None or img.size == 0:
        raise DatasetError(
            f"{dataset} image unreadable: expected a decodable image at {path}, "
            f"found {path.stat().st_size} bytes opencv cannot decode"
        )
    return img


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_START, JPEG_END = b"\xff\xd8", b"\xff\xd9"
_PNG_KINDS = {0: "gray", 2: "rgb", 3: "palette", 4: "gray+alpha", 6: "rgba"}  # IHDR colour type
_TAIL_BYTES = 4096  # where a whole file's end marker must be (a file may carry a few bytes after its end)


def png_header(path: Path) -> tuple[int, str] | None:
    """``(bit depth, kind)`` from a PNG's IHDR chunk (kind: gray, rgb, ...), or None for a file that is not a PNG."""
    with open(path, "rb") as fh:
        head = fh.read(26)
    if len(head) < 26 or not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return None
    return head[24], _PNG_KINDS.get(head[25], f"colour type {head[25]}")


def png_kind(bits: int, kind: str = "") -> str:
    """``an 8-bit gray png``, ``a 16-bit png``: a PNG's sample depth (and kind) as a message names it."""
    article = "an" if bits in (8, 11, 18) else "a"
    return f"{article} {bits}-bit {kind + ' ' if kind else ''}png"


def check_image_file(path: Path, dataset: str, bits: int | None = None) -> None:
    """Refuse, from the file's bytes and without decoding it, a PNG or JPEG cut short (no end chunk or marker),
    and, with ``bits``, a PNG whose samples are deeper than ``bits`` (a 16-bit PNG where 8-bit frames are
    expected: decoded to 8 bits it reads as a near-black frame). Other formats are left to the decoder."""
    with open(path, "rb") as fh:
        head = fh.read(2)
        fh.seek(max(0, path.stat().st_size - _TAIL_BYTES))
        tail = fh.read()
    header = png_header(path)
    if header is not None:
        if b"IEND" not in tail:
            raise DatasetError(f"{dataset} image {path}: expected a whole png, found one cut short (no IEND chunk)")
        if bits is not None and header[0] > bits:
            raise DatasetError(f"{dataset} image {path}: expected {png_kind(bits)}, found {png_kind(*header)}")
    elif head == JPEG_START and JPEG_END not in tail:
        raise DatasetError(f"{dataset} image {path}: expected a whole jpeg, found one cut short (no end marker)")


def check_size(img: np.ndarray, path: Path, width: int, height: int, dataset: str) -> None:
    if img.shape[0] != height or img.shape[1] != width:
        raise DatasetError(
            f"{dataset} image {path}: expected {width}x{height} (the calibrated size), "
            f"found {img.shape[1]}x{img.shape[0]}"
        )


def rgb_tensor(img: np.ndarray, downscale: int) -> torch.Tensor:
    """uint8 gray [H, W] or BGR [H, W, 3] -> float32 RGB [h, w, 3] in [0, 1], area-downscaled."""
    img = downscale_image(img, downscale)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return torch.from_numpy(np.ascontiguousarray(img)).float().div_(255.0)


def downscaled_size(width: int, height: int, factor: int) -> tuple[int, int]:
    """Delivered (width, height): trailing pixels that do not fill a whole block are cropped."""
    return width // factor, height // factor


def downscale_image(img: np.ndarray, factor: int) -> np.ndarray:
    """Block-average by an integer factor (crop to a multiple, then INTER_AREA: exact block means)."""
    if factor == 1:
        return img
    w, h = downscaled_size(img.shape[1], img.shape[0], factor)
    img = img[: h * factor, : w * factor]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def downscale_depth(depth_m: np.ndarray, factor: int, min_valid_fraction: float = 0.5) -> np.ndarray:
    """Valid-aware depth downscale: lower median of the valid pixels of each factor x factor block.

    Averaging would invent "flying" depths across object edges and drag in the zeros of invalid
    pixels; the lower median is always a measured value. A block with fewer than
    ``min_valid_fraction`` valid pixels becomes invalid (0).
    """
    if factor == 1:
        return depth_m.astype(np.float32, copy=False)
    w, h = downscaled_size(depth_m.shape[1], depth_m.shape[0], factor)
    d = depth_m[: h * factor, : w * factor].astype(np.float32, copy=False)
    blocks = d.reshape(h, factor, w, factor).transpose(0, 2, 1, 3).reshape(h, w, factor * factor)
    valid = blocks > 0
    n_valid = valid.sum(axis=2)  # [h, w]
    ordered = np.sort(np.where(valid, blocks, np.inf), axis=2)  # invalid sorts last
    idx = np.clip((n_valid - 1) // 2, 0, None)[:, :, None]
    out = np.take_along_axis(ordered, idx, axis=2)[:, :, 0]  # [h, w]
    out[n_valid < max(1, int(np.ceil(min_valid_fraction * factor * factor)))] = 0.0
    return out.astype(np.float32)


def scale_K(K: np.ndarray, factor: int) -> np.ndarray:
    """Intrinsics [3, 3] after block-downscaling: pixel centres map as u' = (u + 0.5) / f - 0.5."""
    K = np.asarray(K, dtype=np.float64).copy()
    if factor == 1:
        return K
    K[0, 0] /= factor
    K[1, 1] /= factor
    K[0, 2] = (K[0, 2] + 0.5) / factor - 0.5
    K[1, 2] = (K[1, 2] + 0.5) / factor - 0.5
    return K


def select(n: int, cfg: RecordedConfig, log: logging.Logger) -> np.ndarray:
    """Indices picked by ``first``, ``last`` (inclusive, None = end) and ``stride`` out of ``n`` frames."""
    dataset, first, last, stride = cfg.name, cfg.first, cfg.last, cfg.stride
    if n == 0:
        raise DatasetError(f"{dataset}: expected at least one frame, found none")
    if first >= n:
        raise ConfigError(f"{dataset} first={first}: expected a frame index below {n}, the sequence length")
    if last is None:
        last = n - 1
    elif last >= n:
        log.warning("%s last=%d is past the end; clipping to %d (sequence has %d frames)", dataset, last, n - 1, n)
        last = n - 1
    if last < first:
        raise ConfigError(f"{dataset} frame range: expected first <= last, found first={first} last={last}")
    return np.arange(first, last + 1, stride)


def poses_from_tq(t: np.ndarray, q_wxyz: np.ndarray, path: Path, dataset: str) -> np.ndarray:
    """Translations [N, 3] + quaternions [N, 4] -> [N, 4, 4] float64; rejects zero-norm quaternions."""
    norms = np.linalg.norm(q_wxyz, axis=1)
    bad = np.flatnonzero(~(norms > 1e-6))
    if bad.size:
        raise DatasetError(
            f"{dataset} ground truth {path}: expected unit quaternions, found norm {norms[bad[0]]:g} in pose {bad[0]}"
        )
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = quat_to_rotmat(torch.from_numpy(q_wxyz)).numpy()
    T[:, :3, 3] = t
    return T


def check_finite_rows(
    values: np.ndarray, path: Path, dataset: str, what: str, line_numbers: list[int] | None = None
) -> None:
    """Raise on the first row [N, D] holding nan/inf, naming its line (row i is line i + 1 by default)."""
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        row = values[bad[0]]
        found = ", ".join(f"{v:g}" for v in row[~np.isfinite(row)][:3])
        line = line_numbers[bad[0]] if line_numbers is not None else bad[0] + 1
        raise DatasetError(f"{dataset} {what} {path} line {line}: expected finite numbers, found {found}")


def associate_nearest(query_s: np.ndarray, ref_s: np.ndarray, max_diff_s: float) -> np.ndarray:
    """For each query time, the index of the nearest reference time within ``max_diff_s`` (else -1).

    The matching is evo's (``sync.matching_time_indices``), the same that pairs estimate and
    ground truth for the ATE.
    """
    out = np.full(len(query_s), -1, dtype=np.int64)
    if len(ref_s) == 0 or len(query_s) == 0:
        return out
    order = np.argsort(ref_s, kind="stable")
    i_query, i_ref = sync.matching_time_indices(np.asarray(query_s, np.float64), ref_s[order], max_diff=max_diff_s)
    out[np.asarray(i_query, dtype=np.int64)] = order[np.asarray(i_ref, dtype=np.int64)]
    return out


def apply_gt_policy(
    assoc: np.ndarray,
    times_s: np.ndarray,
    cfg: GroundTruthPolicy,
    dataset: str,
    gt_path: Path,
    log: logging.Logger,
) -> np.ndarray:
    """Keep mask [N] for frames given their gt association (-1 = none), per ``gt_missing``.

    ``drop`` (default) removes frames with no ground-truth pose within ``gt_max_diff_s``
    (real EuRoC/TUM ground truth often starts after, or ends before, the cameras) and logs how
    many; ``error`` raises instead. Either way every delivered frame has a pose.
    """
    policy = cfg.gt_missing
    keep = assoc >= 0
    n_miss = int((~keep).sum())
    if n_miss == 0:
        return keep
    max_diff = cfg.gt_max_diff_s
    first_t = times_s[~keep][0]
    if policy == "error" or n_miss == len(keep):
        raise DatasetError(
            f"{dataset} ground truth {gt_path}: expected a pose within {max_diff} s of every frame, "
            f"found none for {n_miss} of {len(keep)} frames (first at t={first_t:.6f} s)"
        )
    log.warning(
        "%s: dropping %d of %d frames with no ground-truth pose within %s s (first at t=%.6f s)",
        dataset,
        n_miss,
        len(keep),
        max_diff,
        first_t,
    )
    return keep
