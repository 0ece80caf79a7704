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
from typing import Any

import numpy as np
import torch

from bench.datasets.base import DatasetConfig, TimedSequence
from bench.errors import ConfigError
from bench.typed import SEED_MAX, as_config, setting

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


def _scene(seed: int, length_m: float) -> list[Box]:
    rng = np.random.default_rng(seed)
    boxes: list[Box] = []
    for side in (-1.0, 1.0):
        z = -10.0
        while z < length_m + 40:
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
        z = rng.uniform(-5, 5)
        while z < length_m + 40:
            x0 = side * rng.uniform(3.8, 4.6)
            w = rng.uniform(0.25, 0.6)
            height = rng.uniform(2.5, 6.0)
            tint = rng.uniform(0.2, 0.9, 3)
            boxes.append(Box(np.array([x0 - w / 2, CAMERA_HEIGHT_M - height, z]),
                             np.array([x0 + w / 2, CAMERA_HEIGHT_M, z + w]), 2, tint))
            z += rng.uniform(3.0, 9.0)
    return boxes


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


@dataclass
class SyntheticConfig(DatasetConfig):
    """``dataset=synthetic``: the scene and the drive; ``seq`` (an integer as a string) overrides ``seed``."""

    name: str = "synthetic"
    seed: int = setting(0, "int", lo=0, hi=SEED_MAX)  # the scene layout (which street); the run's seed does not
    width: int = setting(320, "int", lo=16)  # px; 4x the pixels of 160x96, which the fused rasterizer affords
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
        self.poses = camera_path(n_frames, cfg.speed_m_per_frame, cfg.sway_m)
        super().__init__(f"synthetic/{seed}", np.arange(n_frames) / cfg.fps_hz, self.poses)
        self.width, self.height, self.seed = width, height, seed
        self.run_seed = cfg.run_seed
        # run_seed 0 keeps the texture of the scene seed alone (the scenes of earlier versions)
        self._texture_seed = seed + 7919 * cfg.run_seed
        self.rgb_noise_std, self.depth_noise_rel = cfg.rgb_noise_std, cfg.depth_noise_rel
        self.supersample = cfg.supersample
        fx = 0.5 * width / math.tan(math.radians(cfg.fov_deg) / 2)
        self.K = torch.tensor([[fx, 0, (width - 1) / 2], [0, fx, (height - 1) / 2], [0, 0, 1]], dtype=torch.float32)
        self.boxes = _scene(seed, n_frames * cfg.speed_m_per_frame)
        self._lo = np.stack([b.lo for b in self.boxes])  # [B, 3]
        path = self.poses[:, :3, 3]
        self._sky_centre = np.array([0.0, CAMERA_HEIGHT_M, 0.5 * (path[0, 2] + path[-1, 2])])
        self._sky_radius = 0.5 * abs(path[-1, 2] - path[0, 2]) + SKY_RADIUS_M
        self._hi = np.stack([b.hi for b in self.boxes])
        self._cache: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

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

    def render(self, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Colour [H, W, 3] (supersampled) and exact z-depth [H, W] (pixel centres) for ``c2w``."""
        s = self.supersample
        offs = (np.arange(s) + 0.5) / s - 0.5
        acc = np.zeros((self.height, self.width, 3))
        for oy in offs:
            for ox in offs:
                col, _ = self._cast(c2w, ox, oy)
                acc += col
        _, depth = self._cast(c2w, 0.0, 0.0)
        return np.clip(acc / (s * s), 0, 1), depth

    def _cast(self, c2w: np.ndarray, ox: float, oy: float) -> tuple[np.ndarray, np.ndarray]:
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
        # boxes: slab test, [P, B]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t0 = (self._lo[None] - o) * inv[:, None, :]
            t1 = (self._hi[None] - o) * inv[:, None, :]
        tmin = np.minimum(t0, t1)
        tmax = np.maximum(t0, t1)
        t_enter = np.nanmax(tmin, axis=2)
        t_exit = np.nanmin(tmax, axis=2)
        ok = (t_enter <= t_exit) & (t_enter > 0)
        t_enter = np.where(ok, t_enter, np.inf)
        bi = np.argmin(t_enter, axis=1)
        tb = t_enter[np.arange(P), bi]
        closer = tb < t_best
        t_best[closer] = tb[closer]
        kind[closer] = bi[closer]
        normal_axis[closer] = np.nanargmax(tmin[np.arange(P), bi], axis=1)[closer]
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
        asphalt = (0.27 + 0.12 * value_noise(p[:, 0] * 0.7, p[:, 2] * 0.7, tex + 1)
                   + 0.06 * value_noise(p[:, 0] * 3, p[:, 2] * 3, tex + 4))  # patches and wear, no repeats
        lane = ((np.abs(p[:, 0]) < 0.12) & ((p[:, 2] % 6.0) < 3.0)) | (np.abs(np.abs(p[:, 0]) - 3.6) < 0.12)
        road = np.where(lane, 0.9, asphalt)
        side = np.abs(p[:, 0]) > 4.2  # sidewalk, lighter
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
