"""Trajectory accuracy through evo, so ATE figures match what the field publishes.

Association, Umeyama alignment and the error statistics are evo's own code
(``associate_trajectories``, ``PosePath3D.align``, ``metrics.APE``/``RPE``); this module only
converts types, validates inputs and turns failures into one-line ``MetricError``s. Argument
order follows ``evo_ape tum GT EST -a``: the ground truth is the reference and the estimate is
aligned onto it, which is what the published peer figure (fr2/desk, 0.008119 m) was made with.

TUM files are ``timestamp tx ty tz qx qy qz qw`` (quaternion x, y, z, w on disk); in memory the
quaternion is w, x, y, z like evo.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from evo.core import metrics, sync
from evo.core.trajectory import PoseTrajectory3D
from evo.core.transformations import quaternion_from_matrix

from bench.errors import MetricError
from bench.fileio import open_nofollow
from bench.metrics.timestamp_order import order_problem

ALIGNMENTS = ("se3", "sim3", "none")
MIN_POSES = 3  # Umeyama needs 3 non-collinear points; fewer is not a trajectory error
MAX_DIFF_S = 0.01  # estimate <-> ground-truth timestamp association (the run's eval.max_diff_s default)


@dataclass
class Trajectory:
    """Timestamped camera-to-world poses (positions in metres, unit quaternions)."""

    timestamps_s: np.ndarray  # [N] float64
    positions_m: np.ndarray  # [N, 3] float64
    quat_wxyz: np.ndarray  # [N, 4] float64, w first

    def __post_init__(self) -> None:
        self.timestamps_s = np.asarray(self.timestamps_s, dtype=np.float64).reshape(-1)
        self.positions_m = np.asarray(self.positions_m, dtype=np.float64)
        self.quat_wxyz = np.asarray(self.quat_wxyz, dtype=np.float64)
        n = self.timestamps_s.shape[0]
        if self.positions_m.shape != (n, 3) or self.quat_wxyz.shape != (n, 4):
            raise MetricError(
                f"trajectory shapes disagree: expected timestamps [n], positions [n, 3], "
                f"quaternions [n, 4] with one n; found {list(self.timestamps_s.shape)}, "
                f"{list(self.positions_m.shape)}, {list(self.quat_wxyz.shape)}"
            )
        for name, arr in (
            ("timestamps", self.timestamps_s),
            ("positions", self.positions_m),
            ("quaternions", self.quat_wxyz),
        ):
            if not np.all(np.isfinite(arr)):
                bad = int(np.argwhere(~np.isfinite(arr.reshape(n, -1)).all(axis=1))[0, 0])
                raise MetricError(f"trajectory {name} must be finite: found a non-finite value at pose {bad}")

    def __len__(self) -> int:
        return int(self.timestamps_s.shape[0])

    @classmethod
    def from_c2w(cls, timestamps_s: np.ndarray, c2w: np.ndarray) -> Trajectory:
        """Build from camera-to-world matrices ``[N, 4, 4]`` (the SLAM loop's native form)."""
        c2w = np.asarray(c2w, dtype=np.float64)  # [N, 4, 4]
        if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
            raise MetricError(f"poses must be [n, 4, 4] camera-to-world matrices: found {list(c2w.shape)}")
        quats = np.stack([quaternion_from_matrix(p) for p in c2w]) if len(c2w) else np.zeros((0, 4))
        return cls(np.asarray(timestamps_s), c2w[:, :3, 3], quats)

    def to_evo(self, name: str | None = None) -> PoseTrajectory3D:
        if len(self) == 0:
            raise MetricError("trajectory is empty: expected at least one pose, found 0")
        return PoseTrajectory3D(
            positions_xyz=self.positions_m.copy(),
            orientations_quat_wxyz=self.quat_wxyz.copy(),
            timestamps=self.timestamps_s.copy(),
            name=name,
        )


def read_tum(path: str | Path, allow_duplicates: bool = False) -> Trajectory:
    """Read a TUM trajectory; comments (``#``) and blank lines are skipped, commas accepted.

    Timestamps must strictly increase (evo's ``check()`` demands it too): a duplicate or an
    out-of-order row is an error naming its line. ``allow_duplicates`` keeps repeated stamps (still
    in order) for published files that hold them, e.g. the TUM fr2/desk ground truth (line 10863),
    so a figure computed from them can be reproduced.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise MetricError(f"cannot read trajectory {path}: {exc.strerror or exc}") from None
    rows: list[list[float]] = []
    linenos: list[int] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 8:
            raise MetricError(
                f"{path}:{lineno}: expected 8 fields 'timestamp tx ty tz qx qy qz qw', found {len(fields)}"
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise MetricError(f"{path}:{lineno}: expected 8 numbers, found {line[:80]!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise MetricError(f"{path}:{lineno}: expected finite numbers, found {line[:80]!r}")
        if math.hypot(*values[4:8]) < 1e-12:
            raise MetricError(f"{path}:{lineno}: expected a unit quaternion, found a zero quaternion")
        rows.append(values)
        linenos.append(lineno)
    if not rows:
        raise MetricError(f"{path}: expected TUM poses 'timestamp tx ty tz qx qy qz qw', found none")
    data = np.asarray(rows, dtype=np.float64)  # [N, 8]
    problem = order_problem(data[:, 0], linenos, allow_equal=allow_duplicates)
    if problem:
        raise MetricError(f"{path}:{problem.removeprefix('line ')}")
    quat_wxyz = data[:, [7, 4, 5, 6]]  # file order is x y z w
    return Trajectory(data[:, 0], data[:, 1:4], quat_wxyz)


TUM_HEADER = "# timestamp tx ty tz qx qy qz qw\n"


def _tum_line(t: float, p: np.ndarray, q_wxyz: np.ndarray) -> str:
    w, x, y, z = q_wxyz
    return f"{t:.9f} {p[0]:.17g} {p[1]:.17g} {p[2]:.17g} {x:.17g} {y:.17g} {z:.17g} {w:.17g}\n"


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """Write ``timestamp tx ty tz qx qy qz qw`` lines; full precision so a round trip is exact."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as f:
        f.write(TUM_HEADER)
        for t, p, q in zip(traj.timestamps_s, traj.positions_m, traj.quat_wxyz, strict=True):
            f.write(_tum_line(t, p, q))


class TumAppender:
    """A TUM file written one pose at a time, each line flushed to disk as it is tracked.

    Why: a run that is killed, interrupted or meets a corrupt frame keeps the trajectory of every
    frame it tracked, in the same format ``write_tum`` produces.
    """

    def __init__(self, path: str | Path, append: bool = False) -> None:
        """``append``: continue a file this class wrote (a resumed run), without a second header."""
        self.path = Path(path)
        self._fh = open_nofollow(self.path, "a" if append else "w")
        if not append:
            self._fh.write(TUM_HEADER)
        self._sync()

    def append(self, timestamp_s: float, c2w: np.ndarray) -> None:
        """One pose: ``c2w`` [4, 4] camera-to-world."""
        c2w = np.asarray(c2w, dtype=np.float64)
        self._fh.write(_tum_line(float(timestamp_s), c2w[:3, 3], quaternion_from_matrix(c2w)))
        self._sync()

    def _sync(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> TumAppender:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _associate_align(
    est: Trajectory, gt: Trajectory, align: str, max_diff_s: float
) -> tuple[PoseTrajectory3D, PoseTrajectory3D]:
    """Associate by nearest timestamp and align ``est`` onto ``gt``; returns (gt, est) evo copies.

    ``associate_trajectories`` returns copies, so aligning in place leaves the inputs untouched.
    """
    if align not in ALIGNMENTS:
        raise MetricError(f"unknown alignment: expected one of {', '.join(ALIGNMENTS)}, found {align!r}")
    if not max_diff_s > 0:
        raise MetricError(f"max timestamp difference must be > 0 s: found {max_diff_s}")
    traj_ref, traj_est = gt.to_evo("ground truth"), est.to_evo("estimate")
    try:
        traj_ref, traj_est = sync.associate_trajectories(traj_ref, traj_est, max_diff=max_diff_s)
        count = traj_ref.num_poses
    except sync.SyncException:
        count = 0
    if count < MIN_POSES:
        raise MetricError(
            f"too few associated poses: expected at least {MIN_POSES}, found {count} "
            f"(max timestamp difference {max_diff_s} s; estimate {len(est)} poses, ground truth {len(gt)})"
        )
    if align != "none":
        _align(traj_est, traj_ref, align)
    return traj_ref, traj_est


def _align(traj_est: PoseTrajectory3D, traj_ref: PoseTrajectory3D, align: str) -> tuple[np.ndarray, np.ndarray, float]:
    """evo's Umeyama alignment of ``traj_est`` onto ``traj_ref`` in place: (R [3, 3], t [3], scale)."""
    try:
        rot, trans, scale = traj_est.align(traj_ref, correct_scale=(align == "sim3"))
    except Exception as exc:  # evo's GeometryException / numpy LinAlgError on degenerate input
        raise MetricError(
            f"{align} alignment failed on {traj_ref.num_poses} poses: {str(exc).splitlines()[0].lower()}"
        ) from None
    return rot, trans, float(scale)


def aligned_positions(
    est: Trajectory, gt: Trajectory | None, align: str = "se3", max_diff_s: float = MAX_DIFF_S
) -> np.ndarray:
    """[N, 3] every estimated position in the ground-truth frame, aligned as ``ate`` aligns.

    The alignment is fitted on the associated poses only and applied to all of them (for plots).
    """
    if gt is None or align == "none":
        return est.positions_m.copy()
    traj_ref, traj_est = _associate_align(est, gt, "none", max_diff_s)
    rot, trans, scale = _align(traj_est, traj_ref, align)
    return scale * est.positions_m @ rot.T + trans


def distance_along(positions_m: np.ndarray) -> np.ndarray:
    """[N] metres driven up to each of the positions [N, 3], 0 at the first."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions_m, axis=0), axis=1))])


def path_length_ratio(est: Trajectory, gt: Trajectory, max_diff_s: float = MAX_DIFF_S) -> float | None:
    """Estimated path length / true path length over the associated frames, unaligned.

    A tracker that loses scale at driving speed drives a path that comes out short (< 1) or long
    (> 1) while its SE(3)-aligned ATE can stay small; no alignment is applied, since a Sim(3) fit
    would rescale exactly what this measures (a rigid one leaves lengths as they are). None when
    the true path has no length (a camera that stood still).
    """
    traj_ref, traj_est = _associate_align(est, gt, "none", max_diff_s)
    true_m = float(distance_along(traj_ref.positions_xyz)[-1])
    if not true_m > 0:
        return None
    return float(distance_along(traj_est.positions_xyz)[-1]) / true_m


def window_path_ratios(
    est_m: np.ndarray,  # [N, 3] estimated camera positions, frame by frame
    gt_m: np.ndarray,  # [N, 3] true camera positions of the same frames
    start: int,  # the window's first frame (a position in both arrays); the window ends at the last
) -> dict[str, float | None]:
    """Path lengths of a keyframe window, so a drift shows where it starts (keyframes.csv).

    ``path_length_m``: the true path from frame ``start`` to the last frame; ``path_length_ratio``: the
    estimated path over it; ``path_length_ratio_prefix``: the same ratio from the first frame to the
    last (what ``path_length_ratio`` in metrics.json would read had the drive ended here). Unaligned, as
    ``path_length_ratio``; frames pair by position (no timestamp association). A ratio whose true path
    has no length (the first keyframe, a camera standing still) is None.
    """
    if est_m.shape != gt_m.shape or est_m.ndim != 2 or est_m.shape[-1] != 3:
        raise MetricError(f"window_path_ratios: expected two [N, 3] arrays, found {est_m.shape} and {gt_m.shape}")
    if not 0 <= start < len(est_m):
        raise MetricError(f"window_path_ratios: expected a start in [0, {len(est_m)}), found {start}")
    est_along, gt_along = distance_along(est_m), distance_along(gt_m)  # [N] each
    true_win, true_all = float(gt_along[-1] - gt_along[start]), float(gt_along[-1])
    return {
        "path_length_m": true_win,
        "path_length_ratio": float(est_along[-1] - est_along[start]) / true_win if true_win > 0 else None,
        "path_length_ratio_prefix": float(est_along[-1]) / true_all if true_all > 0 else None,
    }


def drift_components(est: Trajectory, gt: Trajectory, max_diff_s: float = MAX_DIFF_S) -> dict[str, np.ndarray]:
    """Per associated frame, the unaligned position error split into the part within the plane of the
    ground-truth path and the part off it, with the metres driven by then.

    The ATE's alignment hides a drift it can rotate away: a camera that slowly pitches climbs out of
    a flat drive, and an SE(3) fit tilts the whole path back. Unaligned, with the first frame
    anchored as the system anchors it, the off-plane part is that climb. The plane is the
    ground-truth path's least-variance axis (for a drive, the vertical); on a perfectly straight path
    that axis is arbitrary across the line, and the split says little.
    """
    traj_ref, traj_est = _associate_align(est, gt, "none", max_diff_s)
    ref, got = traj_ref.positions_xyz, traj_est.positions_xyz  # [N, 3] each
    centred = ref - ref.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]  # [3] least-variance axis of the path
    err = got - ref  # [N, 3]
    off = err @ normal  # [N]
    return {
        "path_length_m": distance_along(ref),
        "in_plane_err_m": np.linalg.norm(err - off[:, None] * normal, axis=1),
        "off_plane_err_m": np.abs(off),
    }


def ate(est: Trajectory, gt: Trajectory, align: str = "se3", max_diff_s: float = MAX_DIFF_S) -> dict:
    """Absolute trajectory error (translation part) after ``se3``/``sim3``/``none`` alignment.

    ``sim3`` is for monocular-scale estimates; ``se3`` matches the TUM/evo convention.
    """
    traj_ref, traj_est = _associate_align(est, gt, align, max_diff_s)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((traj_ref, traj_est))
    return {
        "ate_rmse_m": float(ape.get_statistic(metrics.StatisticsType.rmse)),
        "ate_mean_m": float(ape.get_statistic(metrics.StatisticsType.mean)),
        "ate_max_m": float(ape.get_statistic(metrics.StatisticsType.max)),
        "ate_alignment": align,
        "ate_num_poses": int(traj_ref.num_poses),
        "ate_max_diff_s": float(max_diff_s),
    }


def rpe(
    est: Trajectory, gt: Trajectory, align: str = "se3", max_diff_s: float = MAX_DIFF_S, delta_frames: int = 1
) -> dict:
    """Relative pose error between poses ``delta_frames`` apart (drift per step).

    Rigid alignment does not change RPE; ``sim3`` matters because it fixes the scale first.
    """
    if delta_frames < 1:
        raise MetricError(f"rpe delta must be >= 1 frame: found {delta_frames}")
    traj_ref, traj_est = _associate_align(est, gt, align, max_diff_s)
    if traj_ref.num_poses <= delta_frames:
        raise MetricError(
            f"too few associated poses for rpe: expected more than {delta_frames}, found {traj_ref.num_poses}"
        )
    out: dict = {}
    for key, relation in (
        ("rpe_trans_rmse_m", metrics.PoseRelation.translation_part),
        ("rpe_rot_rmse_deg", metrics.PoseRelation.rotation_angle_deg),
    ):
        m = metrics.RPE(relation, delta=delta_frames, delta_unit=metrics.Unit.frames, all_pairs=False)
        m.process_data((traj_ref, traj_est))
        out[key] = float(m.get_statistic(metrics.StatisticsType.rmse))
    out["rpe_delta_frames"] = int(delta_frames)
    return out


__all__ = [
    "MAX_DIFF_S",
    "Trajectory",
    "TumAppender",
    "aligned_positions",
    "ate",
    "path_length_ratio",
    "window_path_ratios",
    "read_tum",
    "rpe",
    "write_tum",
]
