"""Microsoft 7-Scenes: ``<root>/<seq>/frame-NNNNNN.{color.png|color.jpg,depth.png,pose.txt}``.

One folder per sequence (the official release's ``<scene>/seq-NN/``); ``root`` is the scene folder
(``/data/7scenes/chess``) and ``seq`` the sequence folder (``seq-01``, or ``01`` / ``1`` for it).
Frames are the ``frame-NNNNNN`` numbers found, in order; timestamps are number / 30 s (the Kinect's
30 Hz; the dataset ships no clock). Colour is the release's PNG or a JPEG copy. Depth PNGs are 16-bit
millimetres; 0 and 65535 mean no reading. Each ``pose.txt`` is a 4x4 camera-to-world matrix in metres
(KinectFusion's tracking, the dataset's ground truth); its rotation is checked to be a rotation within
``pose_tolerance`` and then snapped to the nearest one (the files carry ~1e-4 of non-orthogonality).
Intrinsics from ``camera-intrinsics.txt`` in the sequence folder or the root if present, else the
dataset's documented 585 / 585 / 320 / 240. Colour and depth come from the Kinect's two cameras,
unregistered: they are used as distributed (see datasets/sevenscenes/README.md).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bench.config.settings import as_config, setting
from bench.datasets import realio
from bench.datasets.base import FrameSequence, RecordedConfig
from bench.datasets.tum import TumSequence
from bench.errors import DatasetError

LOG = logging.getLogger("bench.datasets.sevenscenes")
DATASET = "sevenscenes"
FPS = 30.0  # Kinect v1 frame rate; 7-Scenes ships no timestamps
NO_DEPTH = 65535  # the release's marker for a pixel without a reading (0 is one too)
# https://www.microsoft.com/en-us/research/project/rgb-d-dataset-7-scenes/ : "principal point (320,240),
# focal length (585,585)", at 640x480
DEFAULT_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
INTRINSICS_FILE = "camera-intrinsics.txt"
_FRAME = re.compile(r"frame-(\d+)\.(color\.png|color\.jpg|depth\.png|pose\.txt)")


@dataclass
class SevenScenesConfig(RecordedConfig):
    """``dataset=sevenscenes``: Microsoft 7-Scenes (see datasets/sevenscenes/README.md); Kinect v1 depth PNGs."""

    name: str = "sevenscenes"
    root: str = "data/7scenes/chess"  # a scene folder, holding seq-NN/
    default_seq: str = "seq-01"  # folder name, or its number ('01', '1')
    downscale: int = 2  # 640x480 -> 320x240; K scaled to match
    max_depth_m: float | None = 10.0  # Kinect readings beyond this are set to 0; None keeps all
    # eval.protocol=splatam keeps the base's range (every pixel with depth), as for TUM (the same Kinect v1)
    depth_scale: float = setting(1000.0, "float", lo=0.0, lo_open=True)  # PNG value per metre (millimetres)
    # largest |R^T R - I| entry and |det R - 1| a pose may have before it is refused as not a rotation
    pose_tolerance: float = setting(1e-2, "float", lo=0.0, lo_open=True)


SCHEMA = SevenScenesConfig  # the dataset's typed settings, found through its entry point (bench.datasets.schema)


def resolve_seq(seq: str) -> str:
    """'1', '01', 'seq1' -> 'seq-01'; others ('seq-01', 'seq') unchanged."""
    m = re.fullmatch(r"(?:seq-?)?(\d+)", seq)
    return f"seq-{int(m.group(1)):02d}" if m else seq


def canonical_seq(seq: Any) -> str:
    """The one name a sequence is recorded under: '1', '01' -> 'seq-01'."""
    return resolve_seq(str(seq).strip())


def read_pose(path: Path, tolerance: float) -> np.ndarray:
    """A ``frame-NNNNNN.pose.txt`` -> c2w [4, 4] float64, rotation snapped to SO(3); refuses non-rigid ones."""
    try:
        values = [float(v) for v in path.read_text().split()]
    except ValueError:
        raise DatasetError(f"{DATASET} pose {path}: expected 16 numbers (a 4x4 matrix), found text") from None
    if len(values) != 16:
        raise DatasetError(f"{DATASET} pose {path}: expected 16 numbers (a 4x4 matrix), found {len(values)}")
    T = np.array(values, dtype=np.float64).reshape(4, 4)
    if not np.isfinite(T).all():
        bad = ", ".join(f"{v:g}" for v in T[~np.isfinite(T)][:3])
        raise DatasetError(f"{DATASET} pose {path}: expected finite numbers, found {bad}")
    R = T[:3, :3]
    ortho = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    bottom = np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max()
    if ortho > tolerance or abs(det - 1.0) > tolerance or bottom > 1e-6:
        raise DatasetError(
            f"{DATASET} pose {path}: expected a rigid transform (rotation with |R^T R - I| and |det R - 1| "
            f"<= {tolerance:g}, last row 0 0 0 1), found |R^T R - I| = {ortho:.3g}, det R = {det:.4g}, "
            f"last row {' '.join(f'{v:g}' for v in T[3])}"
        )
    U, _, Vt = np.linalg.svd(R)
    T[:3, :3] = U @ Vt  # the nearest rotation (det > 0 is checked above)
    T[3] = [0.0, 0.0, 0.0, 1.0]
    return T


def read_intrinsics(seq_dir: Path, root: Path) -> tuple[np.ndarray, Path | None]:
    """K [3, 3] from ``camera-intrinsics.txt`` (sequence folder, then root), else the documented values."""
    for path in (seq_dir / INTRINSICS_FILE, root / INTRINSICS_FILE):
        if not path.is_file():
            continue
        try:
            K = np.array([float(v) for v in path.read_text().split()], dtype=np.float64)
        except ValueError:
            K = np.zeros(0)
        if K.size != 9 or not np.isfinite(K).all():
            raise DatasetError(
                f"{DATASET} intrinsics {path}: expected a 3x3 matrix (9 finite numbers), "
                f"found {path.read_text()[:60]!r}"
            )
        K = K.reshape(3, 3)
        if not (K[0, 0] > 0 and K[1, 1] > 0) or np.abs(K[2] - [0.0, 0.0, 1.0]).max() > 1e-9:
            raise DatasetError(
                f"{DATASET} intrinsics {path}: expected positive focal lengths and a last row "
                f"0 0 1, found fx={K[0, 0]:g} fy={K[1, 1]:g}, last row {K[2].tolist()}"
            )
        return K, path
    fx, fy, cx, cy = DEFAULT_INTRINSICS
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), None


def list_frames(seq_dir: Path) -> tuple[list[int], list[Path], list[Path], list[Path]]:
    """(frame numbers, colour, depth, pose paths) of every frame, in order; each frame must have all three."""
    found: dict[int, dict[str, Path]] = {}
    for path in seq_dir.iterdir():
        m = _FRAME.fullmatch(path.name)
        if m:
            kind = "color" if m.group(2).startswith("color") else m.group(2).split(".")[0]
            slot = found.setdefault(int(m.group(1)), {})
            if kind == "color" and "color" in slot:  # both a .png and a .jpg: the release's png
                path = min(slot["color"], path, key=lambda p: p.suffix != ".png")
            slot[kind] = path
    if not found:
        raise DatasetError(
            f"{DATASET} sequence {seq_dir}: expected frame-NNNNNN.color.png (or .jpg), .depth.png and .pose.txt "
            f"files, found {realio.listing(seq_dir)}; {realio.readme(DATASET)}"
        )
    numbers = sorted(found)
    for n in numbers:
        missing = [k for k in ("color", "depth", "pose") if k not in found[n]]
        if missing:
            names = {"color": "color.png or .color.jpg", "depth": "depth.png", "pose": "pose.txt"}
            have = ", ".join(sorted(p.name for p in found[n].values()))
            raise DatasetError(
                f"{DATASET} frame {n:06d} in {seq_dir}: expected frame-{n:06d}.{names[missing[0]]} beside "
                f"{have}, found none"
            )
    return (
        numbers,
        [found[n]["color"] for n in numbers],
        [found[n]["depth"] for n in numbers],
        [found[n]["pose"] for n in numbers],
    )


class SevenScenesSequence(TumSequence):
    """Colour + 16-bit depth frames of one 7-Scenes sequence, read lazily (TumSequence's paths, K and scaling;
    7-Scenes' millimetres with 65535 as no reading, and sizes checked against the first frame)."""

    def _check_size(self, img: np.ndarray, path: Path, what: str) -> None:
        if img.shape[:2] != (self.full_height, self.full_width):
            raise DatasetError(
                f"{DATASET} {what} image {path}: expected {self.full_width}x{self.full_height} (the first frame's "
                f"colour image), found {img.shape[1]}x{img.shape[0]}"
            )

    def raw_depth(self, i: int) -> np.ndarray:
        """The 16-bit depth PNG [H, W] of frame ``i`` as stored."""
        path = self.depth_paths[i]
        raw = realio.read_image(path, DATASET, "unchanged")
        if raw.dtype != np.uint16 or raw.ndim != 2:
            chans = 1 if raw.ndim == 2 else raw.shape[2]
            raise DatasetError(
                f"{DATASET} depth image {path}: expected a 16-bit single-channel png, "
                f"found {raw.dtype} with {chans} channels"
            )
        self._check_size(raw, path, "depth")
        return raw

    def depth(self, i: int) -> np.ndarray:
        """Depth [h, w] float32 metres of frame ``i`` (0 = invalid: the file's 0 and 65535, and beyond max_depth_m)."""
        raw = self.raw_depth(i)
        depth = raw.astype(np.float32) / self.depth_scale  # [H, W]
        depth[raw == NO_DEPTH] = 0.0
        if self.max_depth_m is not None:
            depth[depth > self.max_depth_m] = 0.0
        return realio.downscale_depth(depth, self.downscale)

    def load(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        rgb = realio.read_image(self.rgb_paths[i], DATASET, "color")
        self._check_size(rgb, self.rgb_paths[i], "colour")
        return realio.rgb_tensor(rgb, self.downscale), torch.from_numpy(self.depth(i))


def check_sizes(seq: SevenScenesSequence) -> None:
    """Every colour and depth image's size from its header, at open rather than mid-run, and from its bytes
    that it is whole and of the bit depth expected (every depth a 16-bit gray png); the first depth fully."""
    from PIL import Image, UnidentifiedImageError

    seq.raw_depth(0)
    for what, paths in (("colour", seq.rgb_paths), ("depth", seq.depth_paths)):
        for path in paths:
            realio.check_image_file(path, DATASET, 8 if what == "colour" else None)
            header = realio.png_header(path) if what == "depth" else (16, "gray")
            if header != (16, "gray"):
                found = realio.png_kind(*header) if header else "no png"
                raise DatasetError(f"{DATASET} depth image {path}: expected a 16-bit single-channel png, found {found}")
            try:
                with Image.open(path) as img:
                    width, height = img.size
            except (OSError, UnidentifiedImageError):
                realio.read_image(path, DATASET, "unchanged")  # its one-line error
                raise
            if (width, height) != (seq.full_width, seq.full_height):
                raise DatasetError(
                    f"{DATASET} {what} image {path}: expected {seq.full_width}x{seq.full_height} (the first frame's "
                    f"colour image), found {width}x{height}"
                )


def open_sequence(cfg: SevenScenesConfig | Mapping[str, Any]) -> FrameSequence:
    """Open 7-Scenes sequence ``cfg.seq`` (a folder, or 'seq-NN' by its number; settings: ``SevenScenesConfig``)."""
    cfg = as_config(SevenScenesConfig, cfg)
    requested = cfg.default_sequence()
    root = realio.resolve_root(DATASET, cfg.root)
    folder = requested if (root / requested).is_dir() else resolve_seq(requested)
    seq_dir = root / folder
    if not seq_dir.is_dir():
        raise DatasetError(
            f"{DATASET} sequence '{requested}' not found: expected a folder {seq_dir}; {root} has: "
            f"{realio.listing(root)}; {realio.readme(DATASET)}"
        )
    numbers, rgb_paths, depth_paths, pose_paths = list_frames(seq_dir)
    idx = realio.select(len(numbers), cfg, LOG)
    rgb_paths = [rgb_paths[i] for i in idx]
    depth_paths = [depth_paths[i] for i in idx]
    pose_paths = [pose_paths[i] for i in idx]
    gt = np.stack([read_pose(p, cfg.pose_tolerance) for p in pose_paths])  # [N, 4, 4]
    K_full, k_path = read_intrinsics(seq_dir, root)

    first = realio.read_image(rgb_paths[0], DATASET, "color")
    height, width = first.shape[:2]
    sequence = SevenScenesSequence(
        name=f"{DATASET}/{folder}",
        rgb_paths=rgb_paths,
        depth_paths=depth_paths,
        timestamps_s=np.array([numbers[i] for i in idx], dtype=np.float64) / FPS,
        gt_c2w=gt,
        K_full=K_full,
        full_size=(width, height),
        downscale=cfg.downscale,
        depth_scale=cfg.depth_scale,
        max_depth_m=cfg.max_depth_m,
    )
    check_sizes(sequence)
    LOG.info(
        "%s %s: %d frames (%dx%d, intrinsics from %s)",
        DATASET,
        folder,
        len(sequence),
        width,
        height,
        k_path or "the dataset's documented values",
    )
    sequence.source_files = (*([k_path] if k_path else []), *pose_paths, *rgb_paths, *depth_paths)
    return sequence
