"""The embedded default: a synthetic outdoor driving sequence with exact depth.

Frames are made by analytic ray casting of a ground plane, a sky dome and boxes (facades,
hedges, trees), never by the SLAM rasterizer, so the benchmark does not grade its renderer
against itself. The scene mixes what the paper's pruning argument is about: large low-texture
regions (road, sky) and texture-dense ones (facades with windows, noisy vegetation).
Everything is a pure function of the config and two seeds: ``seed`` (or ``seq``) lays the scene
out (where the buildings, hedges and posts stand), ``run_seed`` (the run's ``seed``) draws the
surface texture and the optional sensor noise. Repeating a run over several ``seed=`` values
therefore shows the same street with different paint and noise, which is what a noise estimate
for one sequence needs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

from bench.config.settings import SEED_MAX, as_config, setting
from bench.datasets.base import DatasetConfig, TimedSequence
from bench.errors import ConfigError, DatasetError

CAMERA_HEIGHT_M = 1.6
SKY_RADIUS_M = 120.0


@dataclass(frozen=True)
class Box:
    lo: np.ndarray  # [3] world min corner
    hi: np.ndarray  # [3] world max corner
    material: int  # 0 facade, 1 vegetation, 2 post
    tint: np.ndarray  # [3] base colour


def _hash_noise(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic lattice noise in [0, 1) from integer coordinates."""
    h = (ix.astype(np.int64) * 73856093) ^ (iy.astype(np.int64) * 19349663) ^ (seed * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF).astype(np.float64) / 65536.0


def value_noise(u: np.ndarray, v: np.ndarray, seed: int) -> np.ndarray:
    """Smooth (bilinear, smoothstep) value noise at continuous coordinates."""
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
    n00 = _hash_noise(iu, iv, seed)
    n10 = _hash_noise(iu + 1, iv, seed)
    n01 = _hash_noise(iu, iv + 1, seed)
    n11 = _hash_noise(iu + 1, iv + 1, seed)
    return (n00 * (1 - fu) + n10 * fu) * (1 - fv) + (n01 * (1 - fu) + n11 * fu) * fv


def _side_boxes(rng: np.random.Generator, side: float, start: float, end: float) -> list[Box]:
    """One side of a street in street coordinates (x lateral, z along): facades and hedges, then posts.

    The draws, and their order, are those of the original straight street, so that street keeps
    its pixels.
    """
    boxes: list[Box] = []
    z = start
    while z < end:
        depth = rng.uniform(6, 14)
        gap = rng.uniform(0.5, 4)
        if rng.random() < 0.65:  # facade block
            x0 = side * rng.uniform(7.0, 9.0)
            height = rng.uniform(5, 14)
            tint = rng.uniform(0.35, 0.85, 3)
            lo = np.array([min(x0, x0 + side * 8), CAMERA_HEIGHT_M - height, z])
            hi = np.array([max(x0, x0 + side * 8), CAMERA_HEIGHT_M, z + depth])
            boxes.append(Box(lo, hi, 0, tint))
        else:  # hedge / tree row
            x0 = side * rng.uniform(4.5, 6.0)
            height = rng.uniform(1.0, 4.0)
            tint = np.array([0.15, 0.45, 0.12]) * rng.uniform(0.7, 1.3)
            lo = np.array([min(x0, x0 + side * 2), CAMERA_HEIGHT_M - height, z])
            hi = np.array([max(x0, x0 + side * 2), CAMERA_HEIGHT_M, z + depth])
            boxes.append(Box(lo, hi, 1, tint))
        z += depth + gap
    # posts and tree trunks near the kerb: strong, non-periodic parallax cues along the drive
    z = rng.uniform(start + 5, start + 15)
    while z < end:
        x0 = side * rng.uniform(3.8, 4.6)
        w = rng.uniform(0.25, 0.6)
        height = rng.uniform(2.5, 6.0)
        tint = rng.uniform(0.2, 0.9, 3)
        boxes.append(
            Box(
                np.array([x0 - w / 2, CAMERA_HEIGHT_M - height, z]),
                np.array([x0 + w / 2, CAMERA_HEIGHT_M, z + w]),
                2,
                tint,
            )
        )
        z += rng.uniform(3.0, 9.0)
    return boxes


def _scene(seed: int, length_m: float) -> list[Box]:
    """The straight street (the default route): x lateral, z along the drive."""
    rng = np.random.default_rng(seed)
    return [box for side in (-1.0, 1.0) for box in _side_boxes(rng, side, -10.0, length_m + 40)]


def camera_path(n_frames: int, speed_m_per_frame: float, sway_m: float) -> np.ndarray:
    """Smooth forward drive: c2w [n, 4, 4]; the camera looks along its path tangent."""
    poses = np.zeros((n_frames, 4, 4))
    for i in range(n_frames):
        z = i * speed_m_per_frame
        omega = 2 * math.pi / 60.0
        x = sway_m * math.sin(omega * z)
        dx = sway_m * omega * math.cos(omega * z)
        yaw = math.atan2(dx, 1.0)
        c, s = math.cos(yaw), math.sin(yaw)
        R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # rotation about y (down axis)
        poses[i, :3, :3] = R
        poses[i, :3, 3] = [x, 0.02 * math.sin(0.7 * i), z]  # slight vertical bounce
        poses[i, 3, 3] = 1
    return poses


GRID_BLOCK_M = 40.0  # street spacing of the grid route: a loop round one block is 160 m
TURN_RADIUS_M = 8.0  # corners of the grid route are arcs of this radius
ROAD_CLEAR_M = 3.4  # no box comes nearer than this to a street's centre line (posts stand at 3.5 m and more)
PATH_CLEAR_M = 2.0  # ... nor to the camera's path
SWAY_PERIOD_M = 60.0
ROUTES = ("straight", "grid")  # the straight street's sway period, reused along the other routes


@dataclass
class StreetMap:
    """Street centre lines sampled densely: where boxes may not stand, and the road's paint coordinates."""

    points: np.ndarray  # [S, 2] (x, z) samples every ~0.25 m
    along_m: np.ndarray  # [S] arc length of each sample along its street (dashes of the centre line)

    def __post_init__(self) -> None:
        self.tree = cKDTree(self.points)

    def lateral(self, xz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance to the nearest centre line, arc length there) for points [M, 2]."""
        dist, idx = self.tree.query(xz)
        return dist, self.along_m[idx]


def _densify(poly: np.ndarray, step_m: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Points [S, 2] every ~step_m along a polyline [K, 2], and their arc lengths [S]."""
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return poly[:1].copy(), np.zeros(1)
    q = np.linspace(0.0, s[-1], max(2, int(math.ceil(s[-1] / step_m)) + 1))
    return np.stack([np.interp(q, s, poly[:, 0]), np.interp(q, s, poly[:, 1])], -1), q


def _grid_waypoints(seed: int, length_m: float) -> np.ndarray:
    """Intersections [K, 2] (x, z) of a seeded drive on the street grid, from mid-block heading +z.

    It first goes once round a block (the loop's side drawn from the seed) and comes back onto the
    street it started on, in the same direction: the revisit. Then it goes straight, left or right
    at each crossing (1/2, 1/4, 1/4), never back, until it is long enough.
    """
    rng = np.random.default_rng([seed, 7])
    turn = 1 if rng.random() < 0.5 else -1  # +1: the loop turns right (+x when heading +z), -1: left
    b = GRID_BLOCK_M
    # start, the first crossing, round the block, back through the first crossing onto the first street
    corners = [(0.0, -0.5 * b), (0.0, 0.0), (0.0, b), (turn * b, b), (turn * b, 0.0), (0.0, 0.0), (0.0, b)]
    pts = [np.array(p) for p in corners]
    heading = np.array([0.0, 1.0])
    total = 5.5 * b
    while total < length_m + 2 * b:
        r = rng.random()
        if r < 0.25:
            heading = np.array([heading[1], -heading[0]])  # right
        elif r < 0.5:
            heading = np.array([-heading[1], heading[0]])  # left
        pts.append(pts[-1] + b * heading)
        total += b
    return np.stack(pts)


def _round_corners(waypoints: np.ndarray, radius_m: float) -> np.ndarray:
    """A polyline [K', 2] through the waypoints with every turn replaced by a circular arc."""
    out = [waypoints[0]]
    for k in range(1, len(waypoints) - 1):
        w = waypoints[k]
        a = w - waypoints[k - 1]
        b = waypoints[k + 1] - w
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        if abs(float(a @ b)) > 1 - 1e-9:  # straight on
            out.append(w)
            continue
        p1, p2 = w - radius_m * a, w + radius_m * b
        centre = p1 + radius_m * b
        th1 = math.atan2(p1[1] - centre[1], p1[0] - centre[0])
        th2 = math.atan2(p2[1] - centre[1], p2[0] - centre[0])
        dth = (th2 - th1 + math.pi) % (2 * math.pi) - math.pi
        th = th1 + dth * np.linspace(0.0, 1.0, 33)
        out.extend(centre + radius_m * np.stack([np.cos(th), np.sin(th)], -1))
    out.append(waypoints[-1])
    return np.stack(out)


def path_poses(track: np.ndarray, n_frames: int, speed_m_per_frame: float, sway_m: float) -> np.ndarray:
    """c2w [n, 4, 4] driving along a ground track [K, 2] (x, z), swaying sideways like the straight street.

    The camera looks along the tangent of the swayed path, 1.6 m above the ground, with the
    straight street's slight vertical bounce.
    """
    dense, s = _densify(track, 0.05)
    need = (n_frames - 1) * speed_m_per_frame
    if s[-1] < need:
        raise ConfigError(f"synthetic route: expected a track of at least {need:.1f} m, found {s[-1]:.1f} m")
    omega = 2 * math.pi / SWAY_PERIOD_M

    def at(q: np.ndarray) -> np.ndarray:
        q = np.clip(q, 0.0, s[-1])
        base = np.stack([np.interp(q, s, dense[:, 0]), np.interp(q, s, dense[:, 1])], -1)
        h = 0.05
        tan = np.stack(
            [
                np.interp(q + h, s, dense[:, 0]) - np.interp(q - h, s, dense[:, 0]),
                np.interp(q + h, s, dense[:, 1]) - np.interp(q - h, s, dense[:, 1]),
            ],
            -1,
        )
        tan /= np.linalg.norm(tan, axis=1, keepdims=True)
        normal = np.stack([tan[:, 1], -tan[:, 0]], -1)  # +x when heading +z
        return base + (sway_m * np.sin(omega * q))[:, None] * normal

    q = np.arange(n_frames) * speed_m_per_frame
    pos = at(q)
    fwd = at(q + 0.05) - at(q - 0.05)
    return _poses_from_track(pos, fwd, 0.02 * np.sin(0.7 * np.arange(n_frames)))


def _poses_from_track(pos: np.ndarray, fwd: np.ndarray, y: np.ndarray) -> np.ndarray:
    """c2w [n, 4, 4] at ground positions [n, 2] (x, z) looking along [n, 2], level, at heights y [n]."""
    yaw = np.arctan2(fwd[:, 0], fwd[:, 1])
    c, s = np.cos(yaw), np.sin(yaw)
    poses = np.zeros((len(pos), 4, 4))
    poses[:, 0, 0], poses[:, 0, 2], poses[:, 1, 1], poses[:, 2, 0], poses[:, 2, 2] = c, s, 1.0, -s, c
    poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3], poses[:, 3, 3] = pos[:, 0], y, pos[:, 1], 1.0
    return poses


def read_route_file(path: str, n_frames: int) -> np.ndarray:
    """The first ``n_frames`` c2w [n, 4, 4] of a KITTI-format poses file, flattened onto the ground.

    Each line holds a 3x4 camera-to-world matrix, row-major, camera axes x right, y down, z
    forward. The synthetic ground is a plane, so the drive keeps the file's ground track (x, z) and
    heading and drops its height, pitch and roll.
    """
    p = Path(path).expanduser()
    if not p.is_file():
        raise DatasetError(f"synthetic route_file: expected a KITTI poses file, found no file at {p}")
    rows = []
    for k, line in enumerate(p.read_text(errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        try:
            vals = [float(v) for v in line.split()]
        except ValueError:
            vals = []
        if len(vals) != 12 or not all(math.isfinite(v) for v in vals):
            raise DatasetError(
                f"synthetic route_file {p}: expected 12 finite numbers per line (KITTI poses), "
                f"found '{line.strip()[:60]}' on line {k}"
            )
        rows.append(vals)
        if len(rows) == n_frames:
            break
    if len(rows) < n_frames:
        raise DatasetError(f"synthetic route_file {p}: expected at least n_frames={n_frames} poses, found {len(rows)}")
    m = np.asarray(rows).reshape(-1, 3, 4)
    ground = m[:, [0, 2], 3]  # [n, 2] the ground track: the street is laid along it
    if np.linalg.norm(np.diff(ground, axis=0), axis=1).sum() <= 1e-6:
        raise DatasetError(
            f"synthetic route_file {p}: expected a route that moves along the ground, found all "
            f"{len(m)} poses at one spot"
        )
    fwd = m[:, [0, 2], 2]  # [n, 2] the camera's z axis on the ground
    if (np.linalg.norm(fwd, axis=1) < 1e-6).any():
        raise DatasetError(
            f"synthetic route_file {p}: expected cameras looking along the ground, found one "
            "looking straight up or down"
        )
    return _poses_from_track(m[:, [0, 2], 3], fwd, np.zeros(len(m)))


def _along_track_boxes(rng: np.random.Generator, track: np.ndarray) -> list[Box]:
    """The straight street's facades, hedges and posts laid along a ground track [K, 2], both sides.

    Boxes stay axis-aligned: each is placed at its spot along the track, its footprint turned to the
    nearer world axis (a diagonal street is lined with a staircase of blocks).
    """
    dense, s = _densify(track)
    if s[-1] <= 0:
        return []
    tan = np.gradient(dense, axis=0)
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-12)
    boxes = []
    for side in (-1.0, 1.0):
        for box in _side_boxes(rng, side, 0.0, float(s[-1])):
            a_c, l_c = 0.5 * (box.lo[2] + box.hi[2]), 0.5 * (box.lo[0] + box.hi[0])
            half_a, half_l = 0.5 * (box.hi[2] - box.lo[2]), 0.5 * (box.hi[0] - box.lo[0])
            k = min(int(np.searchsorted(s, a_c)), len(s) - 1)
            t = tan[k]
            centre = dense[k] + l_c * np.array([t[1], -t[0]])
            hx, hz = (half_a, half_l) if abs(t[0]) > abs(t[1]) else (half_l, half_a)
            lo = np.array([centre[0] - hx, box.lo[1], centre[1] - hz])
            hi = np.array([centre[0] + hx, box.hi[1], centre[1] + hz])
            boxes.append(Box(lo, hi, box.material, box.tint))
    return boxes


def _grid_streets(route_xz: np.ndarray) -> list[np.ndarray]:
    """Every grid street segment [2, 2] within sight (SKY_RADIUS_M) of the route [n, 2]."""
    b = GRID_BLOCK_M
    lo = np.floor((route_xz.min(0) - SKY_RADIUS_M) / b).astype(int)
    hi = np.ceil((route_xz.max(0) + SKY_RADIUS_M) / b).astype(int)
    segs = []
    for i in range(lo[0], hi[0] + 1):
        for j in range(lo[1], hi[1]):
            segs.append(np.array([[i * b, j * b], [i * b, (j + 1) * b]]))  # along +z
    for j in range(lo[1], hi[1] + 1):
        for i in range(lo[0], hi[0]):
            segs.append(np.array([[i * b, j * b], [(i + 1) * b, j * b]]))  # along +x
    return segs


def _keep_clear(boxes: list[Box], streets: StreetMap, path_xz: np.ndarray) -> list[Box]:
    """The boxes whose footprint stays ROAD_CLEAR_M off every centre line and PATH_CLEAR_M off the path."""
    path_tree = cKDTree(path_xz)
    kept = []
    for box in boxes:
        lo, hi = box.lo[[0, 2]], box.hi[[0, 2]]
        ok = True
        for tree, pts, clear in ((streets.tree, streets.points, ROAD_CLEAR_M), (path_tree, path_xz, PATH_CLEAR_M)):
            near = tree.query_ball_point(0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)) + clear)
            if near:
                q = pts[near]
                gap = np.maximum(np.maximum(lo - q, q - hi), 0.0)
                if float(np.linalg.norm(gap, axis=1).min()) < clear:
                    ok = False
                    break
        if ok:
            kept.append(box)
    return kept


def _street_map(tracks: list[np.ndarray]) -> StreetMap:
    parts = [_densify(t) for t in tracks]
    return StreetMap(np.concatenate([p for p, _ in parts]), np.concatenate([s for _, s in parts]))


@dataclass
class SyntheticConfig(DatasetConfig):
    """``dataset=synthetic``: the scene and the drive; ``seq`` (an integer as a string) overrides ``seed``."""

    name: str = "synthetic"
    seed: int = setting(0, "int", lo=0, hi=SEED_MAX)  # the scene layout (which street); the run's seed does not
    width: int = setting(320, "int", lo=16)  # px; a size the fused rasterizer affords on a CPU
    height: int = setting(192, "int", lo=16)  # px
    n_frames: int = setting(40, "int", lo=2)  # a drive of n_frames x speed_m_per_frame
    speed_m_per_frame: float = setting(0.5, "float", lo=0.0, lo_open=True)
    sway_m: float = setting(1.5, "float", lo=0.0)
    fov_deg: float = setting(80.0, "float", lo=0.0, hi=180.0, lo_open=True)
    supersample: int = setting(2, "int", lo=1)  # rays per pixel along each axis
    fps_hz: float = setting(10.0, "float", lo=0.0, lo_open=True)
    # the run's seed (conf/dataset/synthetic.yaml links it): texture and sensor noise
    run_seed: int = setting(0, "int", lo=0, hi=SEED_MAX)
    # Gaussian colour noise per pixel (0-1 scale), drawn per (run_seed, frame); 0 = off
    rgb_noise_std: float = setting(0.0, "float", lo=0.0)
    depth_noise_rel: float = setting(0.0, "float", lo=0.0)  # Gaussian depth noise, std as a fraction of depth; 0 = off
    # straight: the original street (sway, no turns); grid: a seeded street grid, once round a block
    # and back onto the first street (the revisit), then random turns (speed and sway as above)
    route: str = setting("straight", "str", choices=ROUTES)
    # a KITTI-format poses file: frame i is pose i, on the ground (height, pitch and roll dropped);
    # replaces route, speed_m_per_frame and sway_m; streets are laid along its ground track
    route_file: str | None = setting(None, "path", nullable=True)

    def default_sequence(self) -> str:
        return str(self.scene_seed())

    def scene_seed(self) -> int:
        if self.seq in (None, "", "default"):
            return self.seed
        try:
            return int(self.seq)
        except ValueError:
            raise ConfigError(f"synthetic seq: expected an integer seed, found '{self.seq}'") from None


SCHEMA = SyntheticConfig  # the dataset's typed settings, found through its entry point (bench.datasets.schema)


class SyntheticSequence(TimedSequence):
    """Ray-cast RGB-D frames of the driving scene; frames are rendered on demand and cached."""

    def __init__(self, cfg: SyntheticConfig) -> None:
        seed = cfg.scene_seed()
        width, height, n_frames = cfg.width, cfg.height, cfg.n_frames
        self.streets: StreetMap | None = None  # None: the straight street, painted along world x = 0
        if cfg.route_file:
            self.poses = read_route_file(cfg.route_file, n_frames)
            self.source_files = (Path(cfg.route_file).expanduser(),)
            track = self.poses[:, [0, 2], 3]
            self.streets = _street_map([track])
            boxes = _keep_clear(_along_track_boxes(np.random.default_rng(seed), track), self.streets, track)
            name = f"synthetic/{Path(cfg.route_file).stem}/{seed}"
        elif cfg.route == "grid":
            length = n_frames * cfg.speed_m_per_frame
            track = _round_corners(_grid_waypoints(seed, length), TURN_RADIUS_M)
            self.poses = path_poses(track, n_frames, cfg.speed_m_per_frame, cfg.sway_m)
            segs = _grid_streets(self.poses[:, [0, 2], 3])
            self.streets = _street_map(segs)
            # each street segment draws its own buildings from the scene seed and its place in the grid
            boxes = [
                box
                for seg in segs
                for box in _along_track_boxes(
                    np.random.default_rng(
                        [
                            seed,
                            11,
                            *(int(v) + 2**20 for v in np.round(seg[0] / GRID_BLOCK_M)),
                            int(seg[1, 0] != seg[0, 0]),
                        ]
                    ),
                    seg,
                )
            ]
            boxes = _keep_clear(boxes, self.streets, self.poses[:, [0, 2], 3])
            name = f"synthetic/grid/{seed}"
        else:
            self.poses = camera_path(n_frames, cfg.speed_m_per_frame, cfg.sway_m)
            boxes = _scene(seed, n_frames * cfg.speed_m_per_frame)
            name = f"synthetic/{seed}"
        super().__init__(name, np.arange(n_frames) / cfg.fps_hz, self.poses)
        self.width, self.height, self.seed = width, height, seed
        self.run_seed = cfg.run_seed
        # run_seed 0 keeps the texture of the scene seed alone (the scenes of earlier versions)
        self._texture_seed = seed + 7919 * cfg.run_seed
        self.rgb_noise_std, self.depth_noise_rel = cfg.rgb_noise_std, cfg.depth_noise_rel
        self.supersample = cfg.supersample
        fx = 0.5 * width / math.tan(math.radians(cfg.fov_deg) / 2)
        self.K = torch.tensor([[fx, 0, (width - 1) / 2], [0, fx, (height - 1) / 2], [0, 0, 1]], dtype=torch.float32)
        self.boxes = boxes
        self._lo = np.stack([b.lo for b in self.boxes]).reshape(-1, 3)  # [B, 3]
        self._hi = np.stack([b.hi for b in self.boxes]).reshape(-1, 3)  # [B, 3]
        corner = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], dtype=bool)  # [8, 3]
        self._corners = np.where(corner[None], self._hi[:, None], self._lo[:, None])  # [B, 8, 3]
        path = self.poses[:, :3, 3]
        if self.streets is None:  # the straight street's dome, kept as it was
            self._sky_centre = np.array([0.0, CAMERA_HEIGHT_M, 0.5 * (path[0, 2] + path[-1, 2])])
            self._sky_radius = 0.5 * abs(path[-1, 2] - path[0, 2]) + SKY_RADIUS_M
        else:
            lo, hi = path[:, [0, 2]].min(0), path[:, [0, 2]].max(0)
            self._sky_centre = np.array([0.5 * (lo[0] + hi[0]), CAMERA_HEIGHT_M, 0.5 * (lo[1] + hi[1])])
            self._sky_radius = 0.5 * float(np.linalg.norm(hi - lo)) + SKY_RADIUS_M
        self._cache: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        self.slab_tests = 0  # (ray, box) pairs slab-tested so far: the cast's work, independent of the machine

    def load(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        if i not in self._cache:
            rgb, depth = self.render(self.poses[i])
            rgb, depth = self._sensor_noise(i, rgb, depth)
            self._cache[i] = torch.from_numpy(rgb.astype(np.float32)), torch.from_numpy(depth.astype(np.float32))
        return self._cache[i]

    def _sensor_noise(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gaussian colour noise and depth noise proportional to depth, drawn per (run seed, frame)."""
        if self.rgb_noise_std <= 0 and self.depth_noise_rel <= 0:
            return rgb, depth
        rng = np.random.default_rng([self.run_seed, self.seed, i])
        if self.rgb_noise_std > 0:
            rgb = np.clip(rgb + rng.normal(0.0, self.rgb_noise_std, rgb.shape), 0, 1)
        if self.depth_noise_rel > 0:
            depth = depth * (1.0 + rng.normal(0.0, self.depth_noise_rel, depth.shape))
        return rgb, depth

    def render(self, c2w: np.ndarray, brute_force: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Colour [H, W, 3] (supersampled) and exact z-depth [H, W] (pixel centres) for ``c2w``.

        ``brute_force`` tests every ray against every box of the scene: the reference the culled
        cast must match pixel for pixel (the tests and profiling/synthetic_cost.py compare them).
        """
        s = self.supersample
        offs = (np.arange(s) + 0.5) / s - 0.5
        acc = np.zeros((self.height, self.width, 3))
        for oy in offs:
            for ox in offs:
                col, _ = self._cast(c2w, ox, oy, brute_force)
                acc += col
        _, depth = self._cast(c2w, 0.0, 0.0, brute_force)
        return np.clip(acc / (s * s), 0, 1), depth

    def _box_rects(self, c2w: np.ndarray, ox: float, oy: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The boxes a ray of this cast can hit, nearest first: (index [V], distance m [V], pixel rect [V, 4]).

        A box is left out when it lies beyond the haze (its nearest point SKY_RADIUS_M or more away;
        no hit counts beyond it), wholly behind the camera, or projects outside the image. The rect
        (row0, row1, col0, col1, inclusive, one pixel of margin) bounds the rays that can reach it:
        the bounding box of its projected corners, or the whole image when it straddles the camera
        plane. Each test is conservative, so culling changes no pixel.
        """
        H, W = self.height, self.width
        K = self.K.double().numpy()
        R, o = c2w[:3, :3], c2w[:3, 3]
        gap = np.maximum(np.maximum(self._lo - o, o - self._hi), 0.0)  # [B, 3]
        dist = np.sqrt((gap * gap).sum(1))  # [B] camera to the box's nearest point
        cam = (self._corners - o) @ R  # [B, 8, 3] corners in camera axes
        z = cam[..., 2]
        front = (z > 1e-6).all(1)
        keep = (dist < SKY_RADIUS_M) & (z > 0).any(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K[0, 0] * cam[..., 0] / z + K[0, 2]  # [B, 8]
            v = K[1, 1] * cam[..., 1] / z + K[1, 2]
        rect = np.zeros((len(dist), 4), dtype=np.int64)
        rect[:] = (0, H - 1, 0, W - 1)
        if front.any():
            f = front
            rect[f, 0] = np.floor(v[f].min(1) - oy) - 1
            rect[f, 1] = np.ceil(v[f].max(1) - oy) + 1
            rect[f, 2] = np.floor(u[f].min(1) - ox) - 1
            rect[f, 3] = np.ceil(u[f].max(1) - ox) + 1
        rect[:, 0:2] = np.clip(rect[:, 0:2], 0, H - 1)
        rect[:, 2:4] = np.clip(rect[:, 2:4], 0, W - 1)
        in_image = np.ones(len(dist), dtype=bool)
        if front.any():
            in_image[front] = (
                (v[front].max(1) - oy >= -1)
                & (v[front].min(1) - oy <= H)
                & (u[front].max(1) - ox >= -1)
                & (u[front].min(1) - ox <= W)
            )
        idx = np.nonzero(keep & in_image)[0]
        idx = idx[np.argsort(dist[idx], kind="stable")]
        return idx, dist[idx], rect[idx]

    def _hit_boxes(
        self,
        o: np.ndarray,
        d: np.ndarray,
        dn: np.ndarray,
        t_best: np.ndarray,
        kind: np.ndarray,
        normal_axis: np.ndarray,
        boxes: np.ndarray,
        rects: np.ndarray | None = None,
        dists: np.ndarray | None = None,
    ) -> None:
        """Slab-test the rays against ``boxes`` and keep each ray's nearest hit (ties: the lower box index).

        Updates ``t_best``, ``kind`` and ``normal_axis`` [P] in place. With ``rects``/``dists`` (from
        ``_box_rects``) a box is tested only on the rays of its rect that have no hit nearer than the
        box; without them every ray meets every box at once, the brute-force reference.
        """
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d  # [P, 3]
        if rects is None:  # [P, B] at once, as the original caster
            with np.errstate(divide="ignore", invalid="ignore"):
                t0 = (self._lo[boxes][None] - o) * inv[:, None, :]
                t1 = (self._hi[boxes][None] - o) * inv[:, None, :]
            self.slab_tests += t0.shape[0] * t0.shape[1]
            tmin = np.minimum(t0, t1)
            tmax = np.maximum(t0, t1)
            t_enter = np.nanmax(tmin, axis=2)
            t_exit = np.nanmin(tmax, axis=2)
            ok = (t_enter <= t_exit) & (t_enter > 0) & (t_enter * dn[:, None] < SKY_RADIUS_M)
            t_enter = np.where(ok, t_enter, np.inf)
            P = d.shape[0]
            j = np.argmin(t_enter, axis=1)
            tb = t_enter[np.arange(P), j]
            closer = tb < t_best
            t_best[closer] = tb[closer]
            kind[closer] = boxes[j[closer]]
            normal_axis[closer] = np.nanargmax(tmin[np.arange(P), j], axis=1)[closer]
            return
        assert dists is not None  # rects and dists come together, from _box_rects
        W = self.width
        reach = t_best * dn  # [P] distance to the nearest hit so far (inf: sky)
        for b, dist, (r0, r1, c0, c1) in zip(boxes, dists, rects, strict=True):
            ids = (np.arange(r0, r1 + 1)[:, None] * W + np.arange(c0, c1 + 1)[None]).ravel()
            ids = ids[reach[ids] >= dist * (1 - 1e-9) - 1e-9]  # a ray with a nearer hit cannot see this box
            if not ids.size:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                t0 = (self._lo[b] - o) * inv[ids]  # [A, 3]
                t1 = (self._hi[b] - o) * inv[ids]
            self.slab_tests += ids.size
            tmin = np.minimum(t0, t1)
            tmax = np.maximum(t0, t1)
            t_enter = np.nanmax(tmin, axis=1)
            t_exit = np.nanmin(tmax, axis=1)
            ok = (t_enter <= t_exit) & (t_enter > 0) & (t_enter * dn[ids] < SKY_RADIUS_M)
            cur_t, cur_k = t_best[ids], kind[ids]
            better = ok & ((t_enter < cur_t) | ((t_enter == cur_t) & (cur_k > b)))  # ground (-2) keeps its ties
            if not better.any():
                continue
            hit = ids[better]
            t_best[hit] = t_enter[better]
            kind[hit] = b
            normal_axis[hit] = np.nanargmax(tmin[better], axis=1)
            reach[hit] = t_best[hit] * dn[hit]

    def _road(self, p: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance from the street's centre line, position along it) [P] of ground points ``p`` (``g``)."""
        if self.streets is None:  # the straight street runs along world z at x = 0
            return np.abs(p[:, 0]), p[:, 2]
        lat, along = np.zeros(len(p)), np.zeros(len(p))
        if g.any():
            lat[g], along[g] = self.streets.lateral(p[g][:, [0, 2]])
        return lat, along

    def _cast(self, c2w: np.ndarray, ox: float, oy: float, brute_force: bool = False) -> tuple[np.ndarray, np.ndarray]:
        H, W = self.height, self.width
        K = self.K.double().numpy()
        u, v = np.meshgrid(np.arange(W) + ox, np.arange(H) + oy)
        d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)  # z = 1
        R, o = c2w[:3, :3], c2w[:3, 3]
        d = d_cam.reshape(-1, 3) @ R.T  # [P, 3]; ray parameter t equals camera z-depth
        P = d.shape[0]
        t_best = np.full(P, np.inf)
        kind = np.full(P, -1)  # -1 sky, -2 ground, >= 0 box index
        normal_axis = np.zeros(P, dtype=int)
        # ground plane y = CAMERA_HEIGHT_M (y points down)
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = (CAMERA_HEIGHT_M - o[1]) / d[:, 1]
        dn = np.linalg.norm(d, axis=1)
        hit = (d[:, 1] > 1e-9) & (tg > 0) & (tg * dn < SKY_RADIUS_M)  # the ground ends at the horizon haze
        t_best[hit] = tg[hit]
        kind[hit] = -2
        # boxes (as far as the haze, like the ground): only those this camera can see, nearest first
        if brute_force:
            self._hit_boxes(o, d, dn, t_best, kind, normal_axis, np.arange(len(self.boxes)))
        else:
            idx, dists, rects = self._box_rects(c2w, ox, oy)
            self._hit_boxes(o, d, dn, t_best, kind, normal_axis, idx, rects, dists)
        # sky dome: one static sphere enclosing the whole drive, so the sky is real, consistent geometry
        sky = kind == -1
        oc = o - self._sky_centre
        b = (d @ oc) / dn**2  # [P]
        c = (oc @ oc - self._sky_radius**2) / dn**2
        t_best[sky] = (-b + np.sqrt(b * b - c))[sky]
        p = o + d * t_best[:, None]  # [P, 3] hit points
        col = np.zeros((P, 3))
        # sky: low-texture vertical gradient with faint clouds, a function of the hit point only
        elev = np.clip(-(p[:, 1] - self._sky_centre[1]) / self._sky_radius, 0, 1) ** 0.5
        cloud = value_noise(p[:, 0] / 40, p[:, 2] / 40 + p[:, 1] / 40, self._texture_seed + 7)
        sky_col = (
            np.array([0.55, 0.7, 0.92])[None] * (1 - 0.5 * elev[:, None])
            + np.array([0.85, 0.88, 0.9])[None] * 0.5 * elev[:, None]
        ) + 0.06 * cloud[:, None]
        col[sky] = sky_col[sky]
        # road: dark asphalt, gentle noise, dashed centre line and edge lines
        g = kind == -2
        tex = self._texture_seed
        asphalt = (
            0.27
            + 0.12 * value_noise(p[:, 0] * 0.7, p[:, 2] * 0.7, tex + 1)
            + 0.06 * value_noise(p[:, 0] * 3, p[:, 2] * 3, tex + 4)
        )  # patches and wear, no repeats
        lat, along = self._road(p, g)
        lane = ((lat < 0.12) & ((along % 6.0) < 3.0)) | (np.abs(lat - 3.6) < 0.12)
        road = np.where(lane, 0.9, asphalt)
        side = lat > 4.2  # sidewalk, lighter
        road = np.where(side & ~lane, 0.55 + 0.08 * value_noise(p[:, 0] * 2, p[:, 2] * 2, self._texture_seed + 2), road)
        col[g] = np.stack([road, road, road * 1.05], -1)[g]
        # boxes
        for bidx in np.unique(kind[kind >= 0]):
            m = kind == bidx
            box = self.boxes[bidx]
            q = p[m]
            ax = normal_axis[m]
            # face coordinates: the two axes other than the normal
            a = np.where(ax == 0, q[:, 2], q[:, 0])
            b = q[:, 1]
            if box.material == 0:  # facade: window grid (per-building spacing) over plaster noise
                plaster = 0.8 + 0.2 * value_noise(a * 2, b * 2, self._texture_seed + 3 + bidx)
                plaster = plaster * (0.8 + 0.4 * value_noise(a / 3, b / 3, self._texture_seed + 11 + bidx))
                period = 2.0 + (bidx % 5) * 0.35
                wa = ((a + 0.37 * bidx) % period) / period
                wb = ((b - CAMERA_HEIGHT_M) % 3.0) / 3.0
                window = (wa > 0.25) & (wa < 0.75) & (wb > 0.3) & (wb < 0.75) & (b < CAMERA_HEIGHT_M - 1.5)
                c = box.tint[None] * plaster[:, None]
                c = np.where(window[:, None], np.array([0.12, 0.16, 0.22])[None] + 0.1 * plaster[:, None] - 0.08, c)
            elif box.material == 2:  # post: banded paint
                band = value_noise(b * 1.5, np.full_like(b, float(bidx)), self._texture_seed + 13)
                c = box.tint[None] * (0.6 + 0.6 * band[:, None])
            else:  # vegetation: dense multi-octave noise
                n = (
                    0.5 * value_noise(a * 3, b * 3, self._texture_seed + 5)
                    + 0.3 * value_noise(a * 7, b * 7, self._texture_seed + 6)
                    + 0.2 * value_noise(a * 13, b * 13, self._texture_seed + 9)
                )
                c = box.tint[None] * (0.5 + n[:, None])
            shade = np.where(ax == 1, 0.75, np.where(ax == 0, 1.0, 0.85))  # simple fixed lighting per face
            col[m] = c * shade[:, None]
        return col.reshape(H, W, 3), t_best.reshape(H, W)


def open_sequence(cfg: SyntheticConfig | Mapping[str, Any]) -> SyntheticSequence:
    """Entry point for ``dataset=synthetic``; ``seq`` (if given) overrides the seed."""
    return SyntheticSequence(as_config(SyntheticConfig, cfg))


def canonical_seq(seq: Any) -> str:
    """The one name a sequence is recorded under: the scene seed as a plain integer ('007' -> '7')."""
    text = str(seq).strip()
    return str(int(text)) if text.lstrip("-").isdigit() else text
