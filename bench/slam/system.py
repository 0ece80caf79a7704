"""Tracking and keyframe mapping: a SplaTAM-style RGB-D 3DGS-SLAM loop with a pruning hook.

Per frame: the pose is initialised at constant velocity (refined by sparse flow + PnP on the
previous frame's depth by default, see ``frontend.py``) and refined on SE(3) by Adam on a
twist increment, against L1 colour + lambda_d L1 depth on confidently mapped pixels; the last
tracking iteration also yields the per-Gaussian gradient norm g_i that pruning strategies use.
On a keyframe: Gaussians are added where the map is missing or wrong, the map is optimised
over a window of keyframes, and the strategy's keep mask goes through ``GaussianMap.remove``.
"""

from __future__ import annotations

import contextlib
import logging
import random
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from bench.config.settings import as_config
from bench.datasets.base import Frame
from bench.errors import ConfigError, TrackingLost
from bench.metrics.image import region_psnr_db
from bench.schema import PRUNE_QUARTILE_COLUMNS
from bench.slam.frontend import FlowPnpConfig, relative_motion, to_gray_u8
from bench.slam.gaussians import GaussianMap, LearningRates
from bench.slam.losses import dssim
from bench.slam.raster import BACKENDS, RasterOutput, rasterize
from bench.slam.se3 import inverse, se3_exp, so3_log
from bench.slam.strategy import MappingContext, PruneConfig, PruneContext, Strategy, TrackingContext

log = logging.getLogger(__name__)

MAPPING_SCHEDULES = ("keyframes", "first")
LOST_CHECKS = ("both", "depth", "color", "off")  # slam.lost_check
# lost_check=depth judges a frame once this many frames make its baseline: the depth error a map reaches
# depends on the sensor (exact synthetic depth, noisy stereo), so the first frames are the reference
DEPTH_BASELINE_MIN = 3


@dataclass
class SlamConfig:
    """Backend hyperparameters; the paper's values where it gives them."""

    tracking_iters: int = 20  # from the flow + PnP start, sized for a CPU; the paper's 50: slam=paper
    # the second frame has no constant-velocity guess (it starts at the first pose), and Adam's
    # step bounds how far a pose can travel: ~0.4 x lr x iterations over the decayed schedule
    tracking_iters_first: int = 100
    tracking_lr_trans: float = 5e-2  # Adam step on the twist's translation part (m), decayed ...
    tracking_lr_rot: float = 4e-3  # ... and rotation part (rad)
    tracking_lr_final: float = 0.1  # ... exponentially to this fraction over the iterations
    lambda_depth_track: float = 1.0  # paper
    lambda_depth_map: float = 1.5  # paper
    # mapping's colour term: (1 - w) x L1 + w x D-SSIM, the 3DGS / SplaTAM form (both use 0.2); 0 = L1 alone
    lambda_ssim_map: float = 0.0
    silhouette_min: float = 0.99  # tracking uses pixels the map explains with confidence
    # ... and, when > 0, only those whose depth error is within this x the median error of those pixels, so that
    # a few pixels the map cannot explain (a car that moved on) do not steer the pose: SplaTAM's
    # ignore_outlier_depth_loss at 10 (see _depth_inliers); 0 = off. It does not remove the pull that
    # feature_weight holds (reports/fidelity/README.md, "At the faithful preset")
    tracking_depth_outlier: float = 0.0
    # which pixels tracking compares: "current" re-selects the confident ones at every iterate;
    # "init" fixes them at the initial pose (which falls short when the initial pose is far off).
    tracking_mask: str = "current"
    # where tracking starts: "velocity" extrapolates the last motion; "flow_pnp" (default) refines
    # that prediction with corners tracked since the previous frame and PnP on its depth
    # (bench/slam/frontend.py), falling back to "velocity" when too few corners survive. Why: see
    # the README's "Known limits" (the velocity guess alone is lost on longer drives).
    tracking_init: str = "flow_pnp"
    flow_pnp: FlowPnpConfig = field(default_factory=FlowPnpConfig)  # slam.flow_pnp.NAME=VALUE
    # tracking loss + this x the mean reprojection error (px, L1) of the corners flow + PnP matched (its
    # RANSAC inliers, 3-D from the previous frame's depth); 0 = off. Why: the depth term of the photometric
    # loss follows the map's geometry, which stereo depth leaves wrong on foliage and far facades, and on a
    # straight road it pulls the pose back along the optical axis; the corners hold the scale there. The
    # released LSG-SLAM code adds a feature-warping term for the same reason (use_warp_loss, weight_warp=10);
    # this term is ours, in pixels, not theirs.
    feature_weight: float = 0.0
    depth_loss_max_m: float = 30.0  # far pixels (sky, distant road) only constrain colour
    depth_far_m: float | None = 60.0  # Gaussians beyond this add no depth (see rasterize); None = all do
    depth_normalized: bool = False  # compare depth / silhouette (unbiased where coverage < 1)
    # compositing backend (bench/slam/raster.py): auto = the compiled "fused" kernels on CPU; on CUDA
    # "gsplat" where it is installed (bench/slam/raster_gsplat.py), else the "torch" reference
    raster_backend: str = "auto"
    mapping_iters: int = 100  # paper: 100 per keyframe
    # when keyframes get those iterations: "keyframes" = every keyframe (the paper's text); "first" = the
    # first keyframe only, later keyframes only densify (and prune), as the released Pocket-SLAM code
    # does (`if time_idx < 1` around its mapping loop; +experiment=released)
    mapping_schedule: str = "keyframes"
    mapping_fresh_optimizer: bool = True  # new Adam moments per keyframe, as SplaTAM does
    # keyframes optimised together (current one included); None = all. Half the iterations go to the
    # current keyframe, the rest to a random other one of the window. A short window lets later
    # close-ups overwrite the views of the early drive (figures in the README's "Known limits").
    mapping_window: int | None = None
    # iterations over all keyframes once the drive is over (System.refine), timed apart from the
    # SLAM loop and not in fps; 0 = evaluate the map exactly as mapping left it
    refine_iters: int = 0
    kf_every: int = 3  # a keyframe at least every N frames
    kf_min_trans_m: float = 3.0  # ... or once the camera moved this far since the last one
    kf_min_rot_deg: float = 15.0  # ... or turned this much
    # Densification (new Gaussians on a keyframe). The defaults re-seed far more eagerly than
    # SplaTAM; conf/slam/splatam.yaml holds SplaTAM's rule (silhouette < 0.5, no colour rule,
    # every pixel, opacity 0.5, 1 px seeds). After pruning, the eager rule refills the holes.
    densify_stride: int = 2  # new Gaussians from every N-th pixel in each direction (SplaTAM: 1)
    densify_silhouette: float = 0.95  # add where the rendered silhouette is below this (SplaTAM: 0.5)
    densify_depth_err_mult: float = 50.0  # ... or where depth error > mult x median error (SplaTAM)
    # the median of that rule over: "confident" pixels (valid depth, silhouette > silhouette_min), or
    # the whole "image" with pixels of no depth counting 0 (SplaTAM's depth_error.median())
    densify_err_median: str = "confident"
    densify_color_err: float = 0.15  # ... or where mean-RGB L1 error exceeds this (detail seen closer); <= 0 off
    # seed sigma in pixels at the seed's depth (scale = depth x sigma_px / fx); None = 0.5 x stride + 0.25,
    # so neighbouring seeds overlap at about one sigma. SplaTAM: 1 (scale = depth / focal)
    densify_sigma_px: float | None = None
    init_opacity: float = 0.95  # opaque seeds: tracking needs a confident silhouette early (SplaTAM: 0.5)
    name: str = "default"  # the preset's name (conf/slam/NAME.yaml), recorded as slam_preset in metrics.json
    max_depth_m: float = 150.0  # observed depth beyond this is ignored
    lrs: LearningRates = field(default_factory=LearningRates)  # slam.lrs.NAME=VALUE
    # what declares tracking lost (besides a non-finite pose and a collapsed silhouette), for lost_patience
    # consecutive frames: "depth" = the depth L1 on confidently mapped pixels (those tracking uses, nearer than
    # depth_loss_max_m) above lost_depth_ratio x its median over the last lost_baseline_frames frames that were
    # not flagged (from the 4th tracked frame on), and above lost_depth_floor_m; "color" = the mean colour L1
    # on those pixels above lost_residual; "both" = either flags the frame; "off" = neither (both readings are
    # still logged in track_log). Why both: a pose 1 m off leaves the colour L1 within the range of good frames
    # (road and facades look alike a metre over) while the depth L1 grows several-fold, so the depth check
    # catches the metre; but its baseline follows a map whose error grows (slam=splatam's stalls), and there
    # the colour check is the one that catches a gross loss. Figures: reports/lost_detector/README.md
    # The default stays the colour check: at ratio 3 the depth check also flagged, at the true pose, a frame
    # showing 4% unmapped street (tests/slam/test_system.py), so it is opt-in until its threshold holds.
    lost_check: str = "color"
    lost_depth_ratio: float = 3.0
    lost_depth_floor_m: float = 0.3
    lost_baseline_frames: int = 20
    lost_residual: float = 0.25  # lost_check=color: mean colour L1 on tracked pixels that counts as failure ...
    lost_patience: int = 3  # ... for this many consecutive frames (either check)
    lost_min_silhouette_frac: float = 0.05  # fewer confidently mapped pixels than this = collapsed
    seed: int = 0

    def __post_init__(self) -> None:
        minimum = {"tracking_iters": 1, "tracking_iters_first": 1, "mapping_iters": 0, "mapping_window": 1,
                   "refine_iters": 0, "kf_every": 1, "densify_stride": 1}
        for name, least in minimum.items():
            if getattr(self, name) is not None and getattr(self, name) < least:
                raise ConfigError(f"slam.{name}: expected >= {least}, found {getattr(self, name)}")
        if self.densify_err_median not in ("confident", "image"):
            raise ConfigError(
                f"slam.densify_err_median: expected 'confident' or 'image', found '{self.densify_err_median}'"
            )
        if self.densify_sigma_px is not None and not self.densify_sigma_px > 0:
            raise ConfigError(f"slam.densify_sigma_px: expected > 0 or null, found {self.densify_sigma_px}")
        if not (self.tracking_depth_outlier == 0 or self.tracking_depth_outlier > 1):
            raise ConfigError(
                f"slam.tracking_depth_outlier: expected 0 (off) or > 1, found {self.tracking_depth_outlier}")
        if not self.feature_weight >= 0.0:
            raise ConfigError(f"slam.feature_weight: expected >= 0, found {self.feature_weight}")
        if not 0.0 <= self.lambda_ssim_map <= 1.0:
            raise ConfigError(f"slam.lambda_ssim_map: expected a value in [0, 1], found {self.lambda_ssim_map}")
        if not 0.0 < self.init_opacity < 1.0:
            raise ConfigError(f"slam.init_opacity: expected a value in (0, 1), found {self.init_opacity}")
        if self.mapping_schedule not in MAPPING_SCHEDULES:
            raise ConfigError(f"slam.mapping_schedule: expected one of {', '.join(MAPPING_SCHEDULES)}, "
                              f"found '{self.mapping_schedule}'")
        if self.tracking_mask not in ("current", "init"):
            raise ConfigError(f"slam.tracking_mask: expected 'current' or 'init', found '{self.tracking_mask}'")
        if self.raster_backend not in BACKENDS:
            raise ConfigError(
                f"slam.raster_backend: expected one of {', '.join(BACKENDS)}, found '{self.raster_backend}'"
            )
        if self.lost_check not in LOST_CHECKS:
            raise ConfigError(f"slam.lost_check: expected one of {', '.join(LOST_CHECKS)}, found '{self.lost_check}'")
        if not self.lost_depth_ratio > 1.0:
            raise ConfigError(f"slam.lost_depth_ratio: expected > 1, found {self.lost_depth_ratio}")
        if not self.lost_depth_floor_m >= 0.0:
            raise ConfigError(f"slam.lost_depth_floor_m: expected >= 0, found {self.lost_depth_floor_m}")
        if self.lost_baseline_frames < 1 or self.lost_patience < 1:
            raise ConfigError(f"slam.lost_baseline_frames and slam.lost_patience: expected >= 1, found "
                              f"{self.lost_baseline_frames} and {self.lost_patience}")
        if self.tracking_init not in ("velocity", "flow_pnp"):
            raise ConfigError(f"slam.tracking_init: expected 'velocity' or 'flow_pnp', found '{self.tracking_init}'")
        # a mapping of overrides (SlamConfig(lrs={"colors": 0.5}) from Python) becomes the typed group
        self.lrs = as_config(LearningRates, self.lrs, "slam.lrs")
        self.flow_pnp = as_config(FlowPnpConfig, self.flow_pnp, "slam.flow_pnp")


@dataclass
class FrameResult:
    w2c: torch.Tensor  # [4, 4] estimated world-to-camera
    is_keyframe: bool
    keyframe_index: int | None = None
    n_added: int = 0
    n_pruned: int = 0
    n_candidates: int = 0  # Gaussians the strategy could prune (in view, not new), over this frame's prune calls
    track_loss: float = 0.0
    track_s: float = 0.0
    map_s: float = 0.0
    prune_s: float = 0.0
    # what pruning removed and what came back (keyframes.csv; bench/schema.py, _prune_diagnostics)
    diag: dict[str, float | int | None] = field(default_factory=dict)
    diag_s: float = 0.0  # time spent on those diagnostics (inside prune_s)


REDUNDANT_WEIGHT = 0.05  # a candidate whose blending weight never exceeds this is redundant (reports/fidelity)


@dataclass
class _Keyframe:
    index: int
    rgb: torch.Tensor  # [H, W, 3]
    depth: torch.Tensor  # [H, W]
    w2c: torch.Tensor  # [4, 4]


class System:
    """Owns the map, the keyframes and the pose history of one run."""

    def __init__(
        self,
        cfg: SlamConfig,
        K: torch.Tensor,
        height: int,
        width: int,
        strategy: Strategy,
        prune: PruneConfig | float,
        device: torch.device,
        timer=None,
    ):
        """``prune`` is the pruning schedule, or just the shared keep ratio (the default schedule)."""
        self.prune = prune if isinstance(prune, PruneConfig) else PruneConfig(keep_ratio=float(prune))
        self.cfg, self.strategy, self.keep_ratio, self.device = cfg, strategy, self.prune.keep_ratio, device
        # Adam's second moments and the gradients of far or faint Gaussians fall into float32's
        # denormal range, where CPU arithmetic is tens of times slower; flushing them to zero changes
        # no result that matters and keeps the optimiser step from dominating a CPU run
        torch.set_flush_denormal(True)
        self.K = K.to(device=device, dtype=torch.float32)
        self.H, self.W = height, width
        self.map = GaussianMap(device, lrs=asdict(cfg.lrs), extra=strategy.extra_params(),
                               state_dtypes=strategy.state_spec())
        self.map.state["_track_grad_sum"] = torch.empty(0, device=device)
        self.map.state["_track_grad_n"] = torch.empty(0, device=device)
        self.keyframes: list[_Keyframe] = []
        self.poses: list[torch.Tensor] = []  # w2c per processed frame
        self.frames_since_kf = 0
        self._bad_frames = 0
        self._depth_recent: list[float] = []  # lost_check=depth: depth L1 of the last unflagged frames (the baseline)
        # one generator per consumer, all from the run seed, so that a change in one (say, more
        # keyframes) does not shift the draws of another
        self._rng = random.Random(cfg.seed)  # keyframe sampling in mapping and refinement
        self._densify_rng = np.random.default_rng([cfg.seed, 1])  # seeding-grid offsets per keyframe
        self._ransac_rng = np.random.default_rng([cfg.seed, 2])  # RANSAC sample order (flow + PnP)
        self._timer = timer
        ys, xs = torch.meshgrid(torch.arange(height, device=device), torch.arange(width, device=device), indexing="ij")
        self._pix = torch.stack([xs, ys], -1).float()  # [H, W, 2]
        self._flow_cfg = cfg.flow_pnp
        self._gray: np.ndarray | None = None  # [H, W] uint8 of the frame being processed (flow_pnp)
        self._prev_obs: tuple | None = None  # (gray [H, W] uint8, depth [H, W] float) of the last frame
        self.init_source: list[str] = []  # per tracked frame: "flow_pnp" or "velocity"
        # the frame being tracked: flow + PnP's inlier corners, world points [M, 3] and pixels [M, 2]
        self._features: tuple[torch.Tensor, torch.Tensor] | None = None
        # called after each prune with (kf_idx, w2c, render before [RasterOutput], keep [N before] bool or None)
        self.on_prune: Callable[[int, torch.Tensor, RasterOutput, torch.Tensor | None], None] | None = None
        # world points [M, 3] (numpy, so they stay out of the measured torch memory) of the pixels the
        # prunes since the last densification opened: the next densification counts seeds landing there
        self._holes: list[np.ndarray] = []
        self._reseeded = 0  # seeds of the last densification that landed in those pixels
        # per tracked frame, what the loss detector reads: (frame, colour L1 on confident pixels,
        # fraction of confident pixels, depth L1 in m on confident pixels with depth); a few floats per frame
        self.track_log: list[tuple[int, float, float, float]] = []

    # ------------------------------------------------------------------ rendering
    def render(
        self, w2c: torch.Tensor, stats: bool = False, training: bool = False, iteration: int = 0
    ) -> RasterOutput:
        g = self.map
        op = g.opacities
        mask = self.strategy.render_mask(MappingContext(len(self.keyframes), iteration, g, g.state, training))
        if mask is not None:
            op = op * mask
        return rasterize(g.means, g.log_scales, g.quats, op, g.colors, w2c, self.K, self.W, self.H, stats=stats,
                         depth_far_m=self.cfg.depth_far_m, backend=self.cfg.raster_backend)

    def _phase(self, name: str):
        return self._timer.phase(name) if self._timer is not None else contextlib.nullcontext()

    # ------------------------------------------------------------------ per frame
    def observe(self, frame: Frame) -> tuple[torch.Tensor, torch.Tensor]:
        """The frame as the system uses it: rgb [H, W, 3] and depth [H, W] (0 where invalid) on the device."""
        rgb = frame.rgb.to(self.device)
        depth = frame.depth_m.to(self.device)
        depth = torch.where((depth > 0) & (depth < self.cfg.max_depth_m), depth, torch.zeros_like(depth))
        return rgb, depth

    def process(self, frame: Frame) -> FrameResult:
        rgb, depth = self.observe(frame)
        t0 = time.perf_counter()
        self._gray = to_gray_u8(rgb) if self.cfg.tracking_init == "flow_pnp" else None  # [H, W] uint8
        if not self.poses:
            w2c = torch.eye(4, device=self.device)
            loss = 0.0
        else:
            with self._phase("tracking"):
                w2c, loss = self._track(frame.index, rgb, depth)
        t1 = time.perf_counter()
        if self.cfg.tracking_init == "flow_pnp":
            self._prev_obs = (self._gray, depth.cpu().numpy())
        self.poses.append(w2c)
        self.frames_since_kf += 1
        result = FrameResult(w2c=w2c, is_keyframe=False, track_loss=loss, track_s=t1 - t0)
        if not self._is_keyframe(w2c):
            if self.prune.every == "frame" and self.keyframes:
                # the next keyframe's index: nothing is new on a frame that added no Gaussian
                with self._phase("pruning"):
                    result.n_pruned, result.n_candidates = self._prune(len(self.keyframes), w2c, depth, result)
                result.prune_s = time.perf_counter() - t1
        else:
            kf_idx = len(self.keyframes)
            self.keyframes.append(_Keyframe(frame.index, _torch_owned(rgb), depth, w2c))
            with self._phase("mapping"):
                result.n_added = self._densify(rgb, depth, w2c, kf_idx)
                result.diag["n_reseeded_holes"] = self._reseeded
                mapped = self._map(kf_idx)
            t_fit = time.perf_counter()
            self._fit_diagnostics(result.diag, rgb, depth, w2c)
            result.diag_s += time.perf_counter() - t_fit
            # the map at its largest in the window: after densification, with Adam's moments and
            # (as during each mapping step) a gradient for every parameter
            result.diag["state_map_bytes"] = self.map.state_bytes() + (sum(
                p.numel() * p.element_size() for p in self.map.params.values() if p.grad is None) if mapped else 0)
            t2 = time.perf_counter() - result.diag_s  # the fit diagnostics are not mapping time
            with self._phase("pruning"):
                result.n_pruned, result.n_candidates = self._prune(kf_idx, w2c, depth, result)
            t3 = time.perf_counter()
            result.is_keyframe, result.keyframe_index = True, kf_idx
            result.map_s, result.prune_s = t2 - t1, t3 - t2
            self.frames_since_kf = 0
        return result

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        """Everything that decides the next frames, as tensors and plain values (``torch.load(weights_only=True)``
        reads it back). Keyframe images are not stored: ``load_state_dict`` re-reads them from the sequence
        by index, which is what keeps a checkpoint small (a KITTI keyframe is ~7 MiB of float images).
        Per-frame lists go in as one tensor or string each: ``torch.save`` pays per object, and a long
        drive has thousands of poses."""
        g = self.map
        moments = {}
        for group in g.optimizer.param_groups:
            st = g.optimizer.state.get(group["params"][0])
            if st:
                moments[group["name"]] = dict(st)
        prev = None if self._prev_obs is None else [torch.from_numpy(self._prev_obs[0]),
                                                    torch.from_numpy(self._prev_obs[1])]
        return {
            "params": {k: p.detach() for k, p in g.params.items()},  # no copies: a checkpoint must not raise the peak
            "requires_grad": {k: p.requires_grad for k, p in g.params.items()},
            "moments": moments,
            "birth_kf": g.birth_kf,
            "state": dict(g.state),
            "keyframes": {"index": torch.tensor([kf.index for kf in self.keyframes], dtype=torch.long),
                          "w2c": _stack([kf.w2c for kf in self.keyframes])},  # [K], [K, 4, 4]
            "poses": _stack(self.poses),  # [F, 4, 4]
            "frames_since_kf": self.frames_since_kf,
            "bad_frames": self._bad_frames,
            "depth_recent": torch.tensor(self._depth_recent, dtype=torch.float64),  # [<= lost_baseline_frames]
            "init_source": ",".join(self.init_source),
            "prev_obs": prev,
            "rng": _py_rng_state(self._rng),
            "densify_rng": _np_gen_state(self._densify_rng),
            "ransac_rng": _np_gen_state(self._ransac_rng),
            # prune diagnostics: the opened pixels' world points awaiting the next densification [M, 3]
            "holes": torch.from_numpy(np.concatenate(self._holes) if self._holes else np.zeros((0, 3))),
            "track_log": torch.tensor(self.track_log, dtype=torch.float64).reshape(-1, 4),  # [F, 4]
        }

    def load_state_dict(self, sd: dict[str, Any], frame_at: Callable[[int], Frame]) -> None:
        """Undo ``state_dict``: the map with its Adam moments, the keyframe store (images from
        ``frame_at(index)``), the tracking state and the generators."""
        g = self.map
        if set(sd["params"]) != set(g.params):
            raise ValueError(f"map parameters: expected {sorted(g.params)}, found {sorted(sd['params'])}")
        g.optimizer.state.clear()
        for group in g.optimizer.param_groups:
            name = group["name"]
            new = torch.nn.Parameter(sd["params"][name].to(self.device), requires_grad=sd["requires_grad"][name])
            group["params"][0] = new
            g.params[name] = new
            if name in sd["moments"]:
                # Adam keeps "step" on the CPU (unless capturable); the moments live with the parameter
                g.optimizer.state[new] = {k: v if k == "step" else v.to(self.device)
                                          for k, v in sd["moments"][name].items()}
        g.birth_kf = sd["birth_kf"].to(self.device)
        g.state = {k: v.to(self.device) for k, v in sd["state"].items()}
        self.keyframes = []
        for index, w2c in zip(sd["keyframes"]["index"].tolist(), sd["keyframes"]["w2c"], strict=True):
            rgb, depth = self.observe(frame_at(index))
            self.keyframes.append(_Keyframe(index, _torch_owned(rgb), depth, w2c.to(self.device)))
        self.poses = [p.to(self.device) for p in sd["poses"]]
        self.frames_since_kf, self._bad_frames = sd["frames_since_kf"], sd["bad_frames"]
        self._depth_recent = sd["depth_recent"].tolist()
        self.init_source = sd["init_source"].split(",") if sd["init_source"] else []
        prev = sd["prev_obs"]
        self._prev_obs = None if prev is None else (prev[0].numpy(), prev[1].numpy())
        self._rng.setstate(_py_rng_from(sd["rng"]))
        self._densify_rng.bit_generator.state = sd["densify_rng"]
        self._ransac_rng.bit_generator.state = sd["ransac_rng"]
        holes = sd["holes"].numpy()
        self._holes = [holes] if len(holes) else []
        self.track_log = [(int(f), c, s, d) for f, c, s, d in sd["track_log"].tolist()]

    def _is_keyframe(self, w2c: torch.Tensor) -> bool:
        if not self.keyframes:
            return True
        if self.frames_since_kf >= self.cfg.kf_every:
            return True
        rel = w2c @ inverse(self.keyframes[-1].w2c)
        trans = float(rel[:3, 3].norm())
        rot_deg = float(so3_log(rel[:3, :3]).norm()) * 57.29578
        return trans > self.cfg.kf_min_trans_m or rot_deg > self.cfg.kf_min_rot_deg

    # ------------------------------------------------------------------ tracking
    def initial_pose(self) -> torch.Tensor:
        """Guess for the next frame's world-to-camera pose [4, 4].

        The constant-velocity prediction, refined by sparse flow + PnP when ``tracking_init`` is
        ``flow_pnp`` and enough corners survive (see ``bench/slam/frontend.py`` for why).
        """
        prev = self.poses[-1]
        velocity = prev @ inverse(self.poses[-2]) if len(self.poses) >= 2 else torch.eye(4, device=prev.device)
        if self._gray is not None:
            if self._prev_obs is not None:
                K = self.K.double().cpu().numpy()
                prior = velocity.double().cpu().numpy()
                inliers: list = []
                rel, _ = relative_motion(self._prev_obs[0], self._gray, self._prev_obs[1], K, self._flow_cfg, prior,
                                         rng=self._ransac_rng, inliers_out=inliers if self.cfg.feature_weight else None)
                if rel is not None:
                    if inliers:
                        c2w_prev = inverse(prev).double()
                        pts = torch.as_tensor(inliers[0], device=prev.device) @ c2w_prev[:3, :3].T + c2w_prev[:3, 3]
                        self._features = (pts.float(), torch.as_tensor(inliers[1], dtype=torch.float32,
                                                                        device=prev.device))
                    self.init_source.append("flow_pnp")
                    return torch.as_tensor(rel, dtype=prev.dtype, device=prev.device) @ prev
            self.init_source.append("velocity")
        return velocity @ prev

    def _track(self, frame_index: int, rgb: torch.Tensor, depth: torch.Tensor,
               init: torch.Tensor | None = None) -> tuple[torch.Tensor, float]:
        cfg = self.cfg
        iters = cfg.tracking_iters if len(self.poses) >= 2 else cfg.tracking_iters_first
        self._features = None
        init = self.initial_pose() if init is None else init
        features = self._features
        xi = torch.zeros(6, device=self.device, requires_grad=True)
        opt = torch.optim.Adam([{"params": [xi], "lr": 1.0}])
        gamma = cfg.tracking_lr_final ** (1.0 / max(1, iters - 1))
        sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma)
        scale = torch.tensor([cfg.tracking_lr_trans] * 3 + [cfg.tracking_lr_rot] * 3, device=self.device)
        params = list(self.map.params.values())
        for p in params:
            p.requires_grad_(False)
        loss_val = float("inf")
        out = mask = None
        mean2d_grads = self.prune.grad_source == "means2d_all"
        if mean2d_grads:
            g2d_sum = torch.zeros(len(self.map), device=self.device)  # [N] sum of ||dL/d mean2d|| over iterations
            g2d_n = torch.zeros(len(self.map), device=self.device)  # [N] iterations that rendered the Gaussian
        for it in range(iters):
            last = it == iters - 1
            if last and not mean2d_grads:
                for p in params:
                    p.requires_grad_(True)
            w2c = se3_exp(xi * scale) @ init
            out = self.render(w2c, stats=last)
            if mean2d_grads and out.means2d.requires_grad:
                out.means2d.retain_grad()
            if mask is None or cfg.tracking_mask == "current":
                mask = out.alpha.detach() > cfg.silhouette_min
                if cfg.tracking_depth_outlier > 0:
                    mask &= self._depth_inliers(out, depth, mask)
            loss, color_l1, depth_l1 = self._tracking_loss(out, rgb, depth, mask)
            if features is not None and loss.requires_grad:
                loss = loss + cfg.feature_weight * self._reprojection_px(features, w2c)
            if not loss.requires_grad:  # no Gaussian projects into the image: nothing to track against
                raise TrackingLost(f"tracking lost at frame {frame_index}: no Gaussian of the map is in view")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if mean2d_grads and out.means2d.grad is not None:
                seen = (out.radius_px > 0).float()  # [N]
                g2d_sum += out.means2d.grad.norm(dim=-1) * seen
                g2d_n += seen
            if last:
                loss_val = float(loss.detach())  # read once: the final iterate's loss is the one reported
                if mean2d_grads:
                    self._on_tracked(frame_index, out, g2d_sum / g2d_n.clamp_min(1), g2d_sum, g2d_n)
                else:
                    grad_norm = self._gaussian_grad_norm()
                    self._on_tracked(frame_index, out, grad_norm, grad_norm, torch.ones_like(grad_norm))
                for p in params:
                    p.grad = None
            else:
                opt.step()
                sched.step()
        w2c = w2c.detach()  # the final iterate: the decayed step size makes it the converged one
        if not torch.isfinite(w2c).all():
            raise TrackingLost(f"tracking lost at frame {frame_index}: pose is not finite")
        sil_frac = float((out.alpha.detach() > cfg.silhouette_min).float().mean())
        self.track_log.append((frame_index, float(color_l1), sil_frac, float(depth_l1)))
        if sil_frac < cfg.lost_min_silhouette_frac:
            raise TrackingLost(
                f"tracking lost at frame {frame_index}: silhouette collapsed to {sil_frac:.3f} "
                f"of pixels (expected >= {cfg.lost_min_silhouette_frac})"
            )
        self._check_lost(frame_index, float(color_l1), float(depth_l1))
        return w2c, loss_val

    def depth_lost_threshold_m(self) -> float:
        """The depth L1 (m) above which the next frame counts as bad under ``lost_check=depth``."""
        if len(self._depth_recent) < DEPTH_BASELINE_MIN:  # no reference yet: the first frames set it
            return float("inf")
        return max(self.cfg.lost_depth_floor_m, self.cfg.lost_depth_ratio * float(np.median(self._depth_recent)))

    def _check_lost(self, frame_index: int, color_l1: float, depth_l1: float) -> None:
        """Count consecutive bad frames under ``lost_check`` and raise ``TrackingLost`` at ``lost_patience``."""
        cfg = self.cfg
        if cfg.lost_check == "off":
            return
        why = []
        if cfg.lost_check in ("depth", "both"):
            threshold = self.depth_lost_threshold_m()
            if depth_l1 > threshold:
                why.append(f"depth residual {depth_l1:.3f} m above {threshold:.3f} m "
                           f"({cfg.lost_depth_ratio} x recent median)")
            else:  # flagged frames stay out of the baseline, so a loss cannot raise its own bar
                self._depth_recent = (self._depth_recent + [depth_l1])[-cfg.lost_baseline_frames:]
        if cfg.lost_check in ("color", "both") and color_l1 > cfg.lost_residual:
            why.append(f"colour residual {color_l1:.3f} above {cfg.lost_residual}")
        self._bad_frames = self._bad_frames + 1 if why else 0
        if self._bad_frames >= cfg.lost_patience:
            raise TrackingLost(
                f"tracking lost at frame {frame_index}: {' and '.join(why)} for {self._bad_frames} frames")

    def _reprojection_px(self, features: tuple[torch.Tensor, torch.Tensor], w2c: torch.Tensor) -> torch.Tensor:
        """Mean L1 reprojection error (px) of the frontend's inlier corners at pose ``w2c`` [4, 4]."""
        pts, uv = features  # [M, 3] world, [M, 2] px
        cam = pts @ w2c[:3, :3].T + w2c[:3, 3]  # [M, 3]
        z = cam[:, 2:].clamp_min(1e-3)
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        proj = torch.cat([fx * cam[:, :1] / z + cx, fy * cam[:, 1:2] / z + cy], 1)  # [M, 2]
        return (proj - uv).abs().sum(-1).mean()

    def _depth_inliers(self, out: RasterOutput, depth: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """[H, W] bool: pixels whose depth error is within ``tracking_depth_outlier`` x the median error of the
        tracked pixels with depth, and pixels without depth. SplaTAM's ``ignore_outlier_depth_loss``
        (``scripts/splatam.py`` ``get_loss``: ``depth_error < 10 * depth_error.median()``) takes the median
        over the whole image and drops pixels without depth from both terms; this one takes it over the
        pixels tracking uses, which a sky without depth would otherwise pull towards zero."""
        err = (self._depth(out).detach() - depth).abs()  # [H, W]
        has = mask & (depth > 0)
        if not has.any():
            return torch.ones_like(mask)
        return (err <= self.cfg.tracking_depth_outlier * err[has].median()) | (depth <= 0)

    def _tracking_loss(self, out: RasterOutput, rgb: torch.Tensor, depth: torch.Tensor, mask: torch.Tensor):
        """L1 colour + lambda_d L1 depth, averaged over ``mask`` [H, W]."""
        n = mask.sum().clamp_min(1)
        color_l1 = ((out.color - rgb).abs().sum(-1) * mask).sum() / (3 * n)
        depth_l1 = self._depth_l1(out, depth, mask)
        return color_l1 + self.cfg.lambda_depth_track * depth_l1, color_l1.detach(), depth_l1.detach()

    def _depth_l1(self, out: RasterOutput, depth: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Mean L1 depth error over valid pixels nearer than ``depth_loss_max_m`` (within ``mask``)."""
        dmask = (depth > 0) & (depth < self.cfg.depth_loss_max_m)
        if mask is not None:
            dmask &= mask
        return ((self._depth(out) - depth).abs() * dmask).sum() / dmask.sum().clamp_min(1)

    def _depth(self, out: RasterOutput) -> torch.Tensor:
        if self.cfg.depth_normalized:
            return out.depth / out.alpha.clamp_min(1e-3)
        return out.depth

    def _gaussian_grad_norm(self) -> torch.Tensor:
        sq = torch.zeros(len(self.map), device=self.device)
        for p in self.map.params.values():
            if p.grad is not None:
                sq += p.grad.reshape(len(self.map), -1).pow(2).sum(1)
        return sq.sqrt()  # [N]

    def _on_tracked(self, frame_index: int, out: RasterOutput, grad_norm: torch.Tensor, grad_sum: torch.Tensor,
                    grad_n: torch.Tensor) -> None:
        """``grad_norm`` [N]: this frame's g_i, as strategies see it; ``grad_sum`` / ``grad_n`` [N]: what
        the core's accumulator (read by pocket's tile budgets as the mean) adds for this frame."""
        st = self.map.state
        st["_track_grad_sum"] += grad_sum
        st["_track_grad_n"] += grad_n
        self.strategy.on_tracking_step(TrackingContext(frame_index, len(self.keyframes), self.map, st, out, grad_norm))

    # ------------------------------------------------------------------ mapping
    @torch.no_grad()
    def _densify(self, rgb: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor, kf_idx: int) -> int:
        cfg = self.cfg
        valid = depth > 0
        if len(self.map):
            out = self.render(w2c)
            err = (out.depth - depth).abs()
            if cfg.densify_err_median == "image":  # SplaTAM: over every pixel, those without depth at 0
                med = (err * valid).median()
            else:
                seen = err[valid & (out.alpha > cfg.silhouette_min)]
                med = seen.median() if seen.numel() else err.new_tensor(float("inf"))
            need = (out.alpha < cfg.densify_silhouette) | (
                (err > cfg.densify_depth_err_mult * med) & (out.depth > depth)
            )
            if cfg.densify_color_err > 0:
                need |= (out.color - rgb).abs().mean(-1) > cfg.densify_color_err
        else:
            need = torch.ones_like(valid)
        s = cfg.densify_stride
        oy, ox = (int(o) for o in self._densify_rng.integers(0, s, size=2))  # the grid's phase varies with the seed
        grid = torch.zeros_like(valid)
        grid[oy::s, ox::s] = True
        sel = need & valid & grid
        self._reseeded = self._count_in_holes(sel, depth, w2c)
        if not sel.any():
            return 0
        z = depth[sel]  # [M]
        uv = self._pix[sel]  # [M, 2]
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        p_cam = torch.stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z], -1)
        c2w = inverse(w2c)
        means = p_cam @ c2w[:3, :3].T + c2w[:3, 3]
        sigma_px = 0.5 * s + 0.25 if cfg.densify_sigma_px is None else cfg.densify_sigma_px
        n = z.shape[0]
        init_logit = torch.logit(torch.tensor(cfg.init_opacity)).item()
        self.map.add(
            {
                "means": means,
                "log_scales": torch.log(z * sigma_px / fx)[:, None].repeat(1, 3),
                "quats": torch.tensor([1.0, 0, 0, 0], device=self.device).repeat(n, 1),
                "opacity_logits": torch.full((n,), init_logit, device=self.device),
                "colors": rgb[sel],
            },
            keyframe=kf_idx,
        )
        return n

    def _map(self, kf_idx: int) -> int:
        """Optimise the map over the keyframe window; the iterations run (none after the first
        keyframe with ``mapping_schedule=first``)."""
        cfg = self.cfg
        if cfg.mapping_schedule == "first" and kf_idx > 0:
            return 0
        # the newest keyframes first; older ones keep the views of the early drive from being
        # overwritten by later close-ups (see mapping_window)
        window = self.keyframes[::-1][: cfg.mapping_window or len(self.keyframes)]

        def pick(it: int) -> _Keyframe:
            return window[0] if it % 2 == 0 or len(window) == 1 else self._rng.choice(window[1:])

        self._optimize(kf_idx, cfg.mapping_iters, pick)
        return cfg.mapping_iters

    def refine(self, iters: int, on_step: Callable[[], None] | None = None) -> None:
        """Optimise the finished map over every keyframe, sampled uniformly.

        During the drive a keyframe gets most of its iterations while it is the newest, so the
        views of the early drive end up fitted less well than the last ones. MonoGS ends with the
        same kind of pass (its "colour refinement"); no Gaussian is added or pruned here.
        ``on_step`` is called after each iteration (progress display).
        """
        if iters <= 0 or not self.keyframes:
            return

        def pick(it: int) -> _Keyframe:
            if it and on_step is not None:
                on_step()  # iteration it-1 is done
            return self._rng.choice(self.keyframes)

        self._optimize(len(self.keyframes) - 1, iters, pick)
        if on_step is not None:
            on_step()

    def _optimize(self, kf_idx: int, iters: int, pick: Callable[[int], _Keyframe]) -> None:
        """Adam on the map parameters against L1 colour + lambda_d L1 depth of the picked keyframes."""
        cfg = self.cfg
        for p in self.map.params.values():
            p.requires_grad_(True)
        opt = self.map.optimizer
        if cfg.mapping_fresh_optimizer:
            opt.state.clear()
        for it in range(iters):
            kf = pick(it)
            out = self.render(kf.w2c, training=True, iteration=it)
            color = (out.color - kf.rgb).abs().mean()
            if cfg.lambda_ssim_map > 0:
                color = (1 - cfg.lambda_ssim_map) * color + cfg.lambda_ssim_map * dssim(out.color, kf.rgb)
            loss = color + cfg.lambda_depth_map * self._depth_l1(out, kf.depth)
            extra = self.strategy.mapping_loss(MappingContext(kf_idx, it, self.map, self.map.state, True))
            if extra is not None:
                loss = loss + extra
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        opt.zero_grad(set_to_none=True)

    # ------------------------------------------------------------------ pruning
    def _prune(self, kf_idx: int, w2c: torch.Tensor, depth: torch.Tensor,
               result: FrameResult | None = None) -> tuple[int, int]:
        """(Gaussians removed, candidates) after the strategy's keep mask at pose ``w2c``; the
        diagnostics of this prune go to ``result.diag`` (``depth`` [H, W]: the frame's observed depth)."""
        with torch.no_grad():
            out = self.render(w2c, stats=True)
        st = self.map.state
        grad_mean = st["_track_grad_sum"] / st["_track_grad_n"].clamp_min(1)
        is_new = self.map.birth_kf == kf_idx
        candidates = (out.tile_id >= 0) & ~is_new
        ctx = PruneContext(kf_idx, self.map, st, out, grad_mean, is_new, candidates, self.keep_ratio,
                           (self.H, self.W), self.prune.target_count)
        keep = self.strategy.after_mapping(ctx)
        st["_track_grad_sum"].zero_()
        st["_track_grad_n"].zero_()
        n_candidates = int(candidates.sum())
        if keep is not None:
            keep = keep.to(torch.bool) | is_new  # new Gaussians are exempt whatever the strategy says
        n_removed = 0 if keep is None else self.map.remove(keep)
        if self.on_prune is not None:  # viz.pruning (figures.pruned_run): `out` is the render before the prune
            self.on_prune(kf_idx, w2c, out, keep)
        if result is not None:
            t0 = time.perf_counter()
            self._prune_diagnostics(result.diag, out, candidates, keep, n_removed, w2c, depth)
            result.diag_s += time.perf_counter() - t0
        return n_removed, n_candidates

    # ------------------------------------------------------------------ diagnostics
    @torch.no_grad()
    def _fit_diagnostics(self, diag: dict, rgb: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> None:
        """How well mapping fitted the keyframe it just mapped: PSNR of its own render over the whole image,
        over the pixels with observed depth (which a map seeds) and over those without (which only
        neighbouring Gaussians can cover). The split says where a map's decibels are lost."""
        out = self.render(w2c)
        sq = (out.color.clamp(0, 1) - rgb).pow(2).mean(-1)  # [H, W]
        has_depth = depth > 0  # [H, W]
        diag["kf_psnr_db"] = region_psnr_db(sq)
        diag["kf_psnr_depth_db"] = region_psnr_db(sq, has_depth)
        diag["kf_psnr_nodepth_db"] = region_psnr_db(sq, ~has_depth)
        diag["kf_depth_frac"] = float(has_depth.float().mean())

    @torch.no_grad()
    def _prune_diagnostics(self, diag: dict, out: RasterOutput, candidates: torch.Tensor, keep: torch.Tensor | None,
                           n_removed: int, w2c: torch.Tensor, depth: torch.Tensor) -> None:
        """What this prune saw and did, at the pruning pose: the candidates' C_i and max blending
        weight quartiles, the redundant candidates (weight never above REDUNDANT_WEIGHT in this view)
        and how many of them were pruned, and the pixels the prune pushed below the densification
        threshold (holes). Costs one extra render, only when something was removed."""
        cand_cov = out.coverage[candidates].float()  # [C]
        cand_w = out.max_weight[candidates].float()  # [C]
        q = torch.tensor([0.25, 0.5, 0.75], device=cand_cov.device)
        cov_q = torch.quantile(cand_cov, q).tolist() if cand_cov.numel() else [None] * 3
        w_q = torch.quantile(cand_w, q).tolist() if cand_w.numel() else [None] * 3
        diag.update(zip(PRUNE_QUARTILE_COLUMNS, [*cov_q, *w_q], strict=True))
        redundant = candidates & (out.max_weight <= REDUNDANT_WEIGHT)  # [N] before removal
        diag["n_redundant"] = diag.get("n_redundant", 0) + int(redundant.sum())
        pruned_redundant = 0 if keep is None else int((redundant & ~keep).sum())
        diag["n_pruned_redundant"] = diag.get("n_pruned_redundant", 0) + pruned_redundant
        holes = 0
        if n_removed:
            after = self.render(w2c)
            thr = self.cfg.densify_silhouette
            opened = (out.alpha >= thr) & (after.alpha < thr)  # [H, W]
            holes = int(opened.sum())
            sel = opened & (depth > 0)
            if sel.any():
                z = depth[sel]
                uv = self._pix[sel]
                fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
                p_cam = torch.stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z], -1)
                c2w = inverse(w2c)
                self._holes.append((p_cam @ c2w[:3, :3].T + c2w[:3, 3]).cpu().numpy().astype(np.float64))
        diag["n_hole_px"] = diag.get("n_hole_px", 0) + holes

    def _count_in_holes(self, sel: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> int:
        """Seeds (``sel`` [H, W]) in pixels the prunes since the last densification opened.

        The opened pixels' surface points (from their frames' observed depth) are projected into
        this keyframe; a point counts where it is the visible surface (within 5% of this frame's
        depth) and marks its pixel and the 8 around it (projected points of another view leave gaps).
        """
        if not self._holes:
            return 0
        pts = np.concatenate(self._holes)  # [M, 3] world
        self._holes = []
        w = w2c.double().cpu().numpy()
        cam = pts @ w[:3, :3].T + w[:3, 3]
        K = self.K.double().cpu().numpy()
        z = cam[:, 2]
        front = z > 1e-6
        u = np.round(K[0, 0] * cam[front, 0] / z[front] + K[0, 2]).astype(np.int64)
        v = np.round(K[1, 1] * cam[front, 1] / z[front] + K[1, 2]).astype(np.int64)
        z = z[front]
        inside = (u >= 0) & (u < self.W) & (v >= 0) & (v < self.H)
        u, v, z = u[inside], v[inside], z[inside]
        d = depth.cpu().numpy()
        seen = np.abs(d[v, u] - z) < 0.05 * z
        mask = np.zeros((self.H + 2, self.W + 2), dtype=bool)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                mask[v[seen] + dy, u[seen] + dx] = True
        opened = mask[1:-1, 1:-1]
        return int((sel.cpu().numpy() & opened).sum())

    def keyframe_store_bytes(self) -> int:
        """Exact bytes of the keyframe store: every keyframe's colour, depth and pose."""
        return int(sum(t.numel() * t.element_size() for kf in self.keyframes for t in (kf.rgb, kf.depth, kf.w2c)))


def _torch_owned(rgb: torch.Tensor) -> torch.Tensor:
    """The keyframe store holds its images in torch's allocator, as on a GPU (where .to() copies): on CPU
    ``rgb`` may be the dataset's numpy-backed frame (synthetic), a storage torch did not allocate (not
    resizable), which the live-tensor peak would never see."""
    return rgb if rgb.untyped_storage().resizable() else rgb.clone()


def _stack(mats: list[torch.Tensor]) -> torch.Tensor:
    return torch.stack(mats) if mats else torch.empty(0, 4, 4)


def _py_rng_state(rng: random.Random) -> list:
    """``random.Random`` state as plain values and one tensor (what ``torch.load(weights_only=True)`` reads)."""
    version, internal, gauss = rng.getstate()
    return [version, torch.tensor(internal, dtype=torch.int64), gauss]  # 625 words < 2**32


def _py_rng_from(state: list) -> tuple:
    return (state[0], tuple(state[1].tolist()), state[2])


def _np_gen_state(gen: np.random.Generator) -> dict[str, Any]:
    return gen.bit_generator.state  # a dict of str and int: loads with weights_only=True
