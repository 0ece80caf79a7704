"""What ``python -m bench.view`` shows, read from run dirs into numpy arrays: no viewer library here.

A run dir gives its final map (``map.ply``) as splats, its estimated and ground-truth trajectories
(``traj_est.txt``, ``traj_gt.txt``), its keyframe cameras (``keyframes.csv`` rows placed at their
frame's estimated pose, with the keyframe's image where the run kept one: ``pruned_kfNNN.npz``,
``density.npz``), its per-keyframe map snapshots (``maps/kf_NNN.npz``, ``save_maps=every_keyframe``)
and the world positions of what each recorded prune removed (``pruned_kfNNN.npz``, ``viz.pruning=true``).
The serving layer (``bench.viewer.serve``) turns a ``RunScene`` into viser scene nodes.
"""

from __future__ import annotations

import csv
import json
import math
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from bench import schema
from bench.errors import ConfigError, MetricError
from bench.metrics.trajectory import read_tum
from bench.report.collect import find_run_dirs
from bench.report.figures.pruned import pruned_records
from bench.run.export import MAP_FILE, SNAPSHOT_DIR, read_ply, read_snapshot, snapshot_keyframes

DEFAULT_VFOV_DEG = 50.0  # keyframe frustums of datasets whose intrinsics the run dir does not hold
DENSITY_FILE = "density.npz"


@dataclass
class Splats:
    """Gaussians as a splat viewer takes them: ``centers`` [N, 3] m, ``covariances`` [N, 3, 3] m^2,
    ``rgbs`` [N, 3] in [0, 1], ``opacities`` [N, 1] in (0, 1)."""

    centers: np.ndarray
    covariances: np.ndarray
    rgbs: np.ndarray
    opacities: np.ndarray

    def __len__(self) -> int:
        return int(self.centers.shape[0])


@dataclass
class KeyframeCamera:
    """A keyframe's camera: its pose at the estimate (``wxyz`` [4], ``position`` [3] m, camera to world,
    OpenCV axes: x right, y down, z forward) and its image [H, W, 3] uint8 where the run kept one."""

    kf: int
    frame: int
    wxyz: np.ndarray
    position: np.ndarray
    image: np.ndarray | None = None


@dataclass
class RunScene:
    """One run dir, ready to draw. Snapshots and pruning records stay on disk until a step shows them."""

    run_dir: Path
    label: str
    splats: Splats  # the final map (map.ply; the last snapshot for a run that ended without one)
    traj_est: np.ndarray  # [F, 3] m, one point per tracked frame
    traj_gt: np.ndarray | None  # [F, 3] m, ground truth with the first camera at the origin, as written
    cameras: list[KeyframeCamera]
    vfov_deg: float  # vertical field of view of the keyframe frustums
    aspect: float  # width / height
    snapshots: dict[int, Path] = field(default_factory=dict)  # keyframe -> maps/kf_NNN.npz
    pruned: dict[int, Path] = field(default_factory=dict)  # keyframe -> pruned_kfNNN.npz

    @property
    def steps(self) -> list[int]:
        """The keyframes a time slider steps through: those with a snapshot or a pruning record."""
        return sorted(set(self.snapshots) | set(self.pruned))


def sigmoid(x: np.ndarray) -> np.ndarray:
    return (1.0 / (1.0 + np.exp(-x.astype(np.float64)))).astype(np.float32)


def quat_to_matrix(wxyz: np.ndarray) -> np.ndarray:
    """[N, 4] quaternions (w x y z, any norm) -> [N, 3, 3] rotation matrices."""
    q = wxyz.astype(np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def splats_from_arrays(arrays: dict[str, np.ndarray]) -> Splats:
    """The map's parameters (``bench.run.export.map_arrays`` keys) as splats: covariance R S S^T R^T from the
    log-scales and the quaternion, opacity the sigmoid of its logit, colours the stored RGB clipped to [0, 1]."""
    rot = quat_to_matrix(arrays["quats"])  # [N, 3, 3]
    scales = np.exp(arrays["log_scales"].astype(np.float64))  # [N, 3] m
    m = rot * scales[:, None, :]  # R S
    return Splats(
        centers=arrays["means"].astype(np.float32),
        covariances=(m @ m.transpose(0, 2, 1)).astype(np.float32),
        rgbs=np.clip(arrays["colors"], 0.0, 1.0).astype(np.float32),
        opacities=sigmoid(arrays["opacity_logits"]).reshape(-1, 1),
    )


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def load_snapshot(path: Path) -> Splats:
    """A ``maps/kf_NNN.npz`` snapshot as splats."""
    return splats_from_arrays(read_snapshot(path))


def load_map(path: Path) -> Splats:
    """A 3DGS ``map.ply`` as splats."""
    try:
        arrays = read_ply(path)
    except (OSError, ValueError, KeyError, IndexError) as exc:
        raise ConfigError(f"expected '{path}' to be a 3DGS PLY map, found: {_first_line(exc)}") from None
    return splats_from_arrays(arrays)


def pruned_points(path: Path) -> np.ndarray | None:
    """The world centres [Q, 3] m of what one recorded prune removed; None for a record written before
    ``pruned_kfNNN.npz`` held them (it has only their image positions)."""
    try:
        with np.load(path) as data:
            return np.asarray(data["xyz"], dtype=np.float32).reshape(-1, 3) if "xyz" in data.files else None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise ConfigError(f"expected '{path}' to be a pruning record, found: {_first_line(exc)}") from None


def is_run_dir(path: Path) -> bool:
    return (Path(path) / schema.METRICS_FILE).is_file()


def has_map(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a map to show (``map.ply``, or a snapshot of a run that ended without one)."""
    return (Path(run_dir) / MAP_FILE).is_file() or bool(snapshot_keyframes(run_dir))


def find_runs(path: Path) -> list[Path]:
    """``[path]`` for a run dir, the run dirs under it (sorted) for a sweep or study dir."""
    path = Path(path)
    if not path.is_dir():
        raise ConfigError(f"expected a run dir or a sweep dir, found no directory at '{path}'")
    if is_run_dir(path):
        return [path]
    runs = find_run_dirs([path])
    if not runs:
        raise ConfigError(
            f"expected a run dir ({schema.METRICS_FILE}) or a sweep dir holding runs, found neither in '{path}'"
        )
    return runs


def run_label(run_dir: Path, root: Path | None = None) -> str:
    """``strategy keep=R seq=S (status)`` from ``metrics.json``, with the dir's path under ``root``."""
    try:
        record = json.loads((Path(run_dir) / schema.METRICS_FILE).read_text())
    except (OSError, ValueError):
        record = {}
    run = record.get("run") or {}
    words = [str(run.get("strategy") or "?")]
    if run.get("keep_ratio") is not None:
        words.append(f"keep={run['keep_ratio']}")
    if run.get("seq") is not None:
        words.append(f"seq={run['seq']}")
    if record.get("status") not in (None, "ok"):
        words.append(f"({record['status']})")
    where = Path(run_dir).relative_to(root).as_posix() if root is not None and Path(run_dir) != root else ""
    return f"{where}: {' '.join(words)}" if where else " ".join(words)


def _trajectory(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """Positions [F, 3] m and quaternions [F, 4] wxyz of a TUM file; None if absent or unreadable."""
    if not path.is_file():
        return None
    try:
        traj = read_tum(path, allow_duplicates=True)
    except MetricError:
        return None
    return traj.positions_m.astype(np.float32), traj.quat_wxyz.astype(np.float32)


def _keyframe_rows(run_dir: Path) -> list[tuple[int, int]]:
    """(keyframe, frame) per row of ``keyframes.csv``."""
    path = run_dir / schema.KEYFRAMES_FILE
    if not path.is_file():
        return []
    rows = []
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            try:
                rows.append((int(row["kf"]), int(row["frame"])))
            except (KeyError, TypeError, ValueError):
                continue
    return rows


def _u8(image: np.ndarray) -> np.ndarray:
    """[H, W, 3] uint8, or float in [0, 1] -> uint8."""
    if image.dtype == np.uint8:
        return image
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def keyframe_images(run_dir: Path, pruned: dict[int, Path], kf_of_frame: dict[int, int]) -> dict[int, np.ndarray]:
    """Keyframe -> its image [H, W, 3] uint8, from the files a run keeps (pruning records, ``density.npz``)."""
    images: dict[int, np.ndarray] = {}
    density = run_dir / DENSITY_FILE
    sources = [(kf, path, None) for kf, path in pruned.items()] + [(None, density, "frame")]
    for kf, path, key in sources:
        if not path.is_file():
            continue
        try:
            with np.load(path) as data:
                if key is not None:
                    kf = kf_of_frame.get(int(data[key]))
                if kf is not None and "image" in data.files and data["image"].ndim == 3:
                    images.setdefault(kf, _u8(np.asarray(data["image"])))
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error):
            continue
    return images


def _dataset_config(run_dir: Path) -> dict:
    """The ``dataset`` block of the run's ``config.yaml`` ({} where unreadable)."""
    try:
        dataset = (yaml.safe_load((run_dir / "config.yaml").read_text()) or {}).get("dataset")
    except (OSError, ValueError, AttributeError, yaml.YAMLError):
        return {}
    return dataset if isinstance(dataset, dict) else {}


def frustum_shape(dataset: dict, image: np.ndarray | None) -> tuple[float, float]:
    """(vertical field of view in degrees, width / height) of the keyframe frustums: the keyframe image's
    size, else the configured one; the synthetic scene's horizontal ``fov_deg``, else ``DEFAULT_VFOV_DEG``
    (the run dir holds no other dataset's intrinsics)."""
    w, h = dataset.get("width"), dataset.get("height")
    if image is not None:
        h, w = image.shape[:2]
    if not (isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0):
        return DEFAULT_VFOV_DEG, 4 / 3
    fov = dataset.get("fov_deg")
    if not isinstance(fov, (int, float)) or not 0 < fov < 180:
        return DEFAULT_VFOV_DEG, w / h
    return math.degrees(2 * math.atan(math.tan(math.radians(fov) / 2) * h / w)), w / h


def read_run(run_dir: Path, label: str | None = None) -> RunScene:
    """Everything the viewer draws for one run dir; a ``ConfigError`` line for a dir that is not a run or
    a run without a map."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"expected a run dir, found no directory at '{run_dir}'")
    if not is_run_dir(run_dir):
        raise ConfigError(f"expected a run dir (with {schema.METRICS_FILE}), found none in '{run_dir}'")
    snapshots = {k: run_dir / SNAPSHOT_DIR / f"kf_{k:03d}.npz" for k in snapshot_keyframes(run_dir)}
    if (run_dir / MAP_FILE).is_file():
        splats = load_map(run_dir / MAP_FILE)
    elif snapshots:
        splats = load_snapshot(snapshots[max(snapshots)])
    else:
        raise ConfigError(
            f"expected a map in '{run_dir}' ({MAP_FILE}, written when a run ends, "
            f"or {SNAPSHOT_DIR}/kf_NNN.npz), found none"
        )
    pruned = pruned_records(run_dir, lambda message: None)  # a misnamed file is no keyframe's record
    est = _trajectory(run_dir / "traj_est.txt")
    gt = _trajectory(run_dir / "traj_gt.txt")
    rows = _keyframe_rows(run_dir)
    images = keyframe_images(run_dir, pruned, {frame: kf for kf, frame in rows})
    cameras = []
    if est is not None and rows:
        first = rows[0][1]  # traj_est.txt has one line per tracked frame from keyframe 0's frame
        for kf, frame in rows:
            if 0 <= frame - first < len(est[0]):
                pos, quat = est[0][frame - first], est[1][frame - first]
                cameras.append(KeyframeCamera(kf, frame, quat, pos, images.get(kf)))
    vfov_deg, aspect = frustum_shape(_dataset_config(run_dir), next(iter(images.values()), None))
    return RunScene(
        run_dir=run_dir,
        label=label if label is not None else run_label(run_dir),
        splats=splats,
        traj_est=est[0] if est is not None else np.zeros((0, 3), np.float32),
        traj_gt=gt[0] if gt is not None else None,
        cameras=cameras,
        vfov_deg=vfov_deg,
        aspect=aspect,
        snapshots=snapshots,
        pruned=pruned,
    )


def extent(scene: RunScene) -> tuple[np.ndarray, np.ndarray]:
    """(low [3], high [3]) m of the map and the trajectory: 1st and 99th percentiles, so a few far-flung
    Gaussians do not set it."""
    points = [scene.splats.centers, scene.traj_est]
    stacked = np.concatenate([p for p in points if len(p)]) if any(len(p) for p in points) else np.zeros((1, 3))
    return np.percentile(stacked, 1, axis=0), np.percentile(stacked, 99, axis=0)


def side_by_side(a: RunScene, b: RunScene, gap: float = 0.1) -> np.ndarray:
    """Where run B's origin goes [3] m so that its map sits beside run A's along x, ``gap`` of A's width apart."""
    lo_a, hi_a = extent(a)
    lo_b, _ = extent(b)
    width = float(hi_a[0] - lo_a[0])
    return np.array([hi_a[0] - lo_b[0] + gap * max(width, 1e-3), 0.0, 0.0], dtype=np.float32)


def overview(bounds: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """(camera position [3], the point it looks at [3]) m that take in every (low, high) box of ``bounds``:
    from behind the start (-z, the first camera looks along +z) and above it (-y: camera y points down); one map
    from a little to its right, maps side by side (along x) from straight behind their middle."""
    lo = np.min([b[0] for b in bounds], axis=0)
    hi = np.max([b[1] for b in bounds], axis=0)
    centre = (lo + hi) / 2
    span = max(float(np.max(hi - lo)), 1e-3)
    direction = np.array([0.3, -0.35, -0.55]) if len(bounds) == 1 else np.array([0.0, -0.5, -0.75])
    return centre + direction * span, centre
