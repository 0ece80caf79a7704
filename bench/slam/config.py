"""The SLAM backend's settings (``slam.*``): ``SlamConfig``, every field with its default and its rule."""

from __future__ import annotations

from dataclasses import dataclass, field

from bench.config.settings import as_config, check_rules, setting
from bench.errors import ConfigError
from bench.slam.frontend import FlowPnpConfig
from bench.slam.gaussians import LearningRates
from bench.slam.keyframes import KeyframeStoreConfig
from bench.slam.raster import BACKENDS
from bench.slam.residency import ResidencyConfig

MAPPING_SCHEDULES = ("keyframes", "first")
MAPPING_DRAWS = ("alternate", "uniform")
TRACKING_MASKS = ("current", "init")
TRACKING_INITS = ("velocity", "flow_pnp")
DENSIFY_ERR_MEDIANS = ("confident", "image")
LOST_CHECKS = ("both", "depth", "color", "off")  # slam.lost_check
DENSIFY_BUDGETS = ("constant", "taming")  # slam.densify.budget
SEED_ORDERS = ("random", "need")  # slam.densify.seed_order
CAP_UNSCORED = ("drop", "opacity")  # slam.densify.unscored


@dataclass
class DensifyConfig:
    """A bound on what densification may add (``slam.densify.*``); null everywhere is today's unbounded rule.

    Why: pruning alone does not bound the map over a drive, since densification re-seeds what a prune
    opens. ``cap`` holds the map's size, in the spirit of gsplat MCMC's ``cap_max``, and is where
    strategies can be compared at equal memory; ``budget`` limits each keyframe's additions, in the
    spirit of Taming 3DGS's budget curve. How both decide what is kept: bench/slam/densify.py and
    docs/architecture.md, "Densification budget".
    """

    # the map holds at most this many Gaussians once a keyframe's seeds are in; at the cap, the strategy's
    # score ranks what is kept (Strategy.cap_score) and the lowest-scored make room for the seeds; null = no cap
    cap: int | None = setting(None, "int", lo=1, nullable=True)
    # the cap as a rule fixed before the runs, not read off them: after keyframe k (0-based) the map holds at most
    # cap_per_mpix_kf x the image's megapixels x (k + 1) Gaussians (the lower of the two where cap is set too)
    cap_per_mpix_kf: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)
    # the rule's floor: its cap is never below this many Gaussians per pixel of one image. Why: the rule alone
    # allows fewer Gaussians after the first keyframes than one view needs, and tracking is lost at once
    # (conf/study/memory_rule.yaml); 1.0 = one view seeded at every pixel
    cap_floor_per_px: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)
    # at the cap, a strategy without a score (none, and every strategy whose score hook returns None):
    # "drop" = no Gaussian is removed, the seeds beyond the cap are not added; "opacity" = rank by opacity
    unscored: str = setting("drop", "str", choices=CAP_UNSCORED)
    # the seeds each keyframe may add: "constant" = per_keyframe each; "taming" = up to Taming 3DGS's curve of
    # the map's size (get_count_array), from the size after keyframe 0 to final_count at final_keyframe; null = all
    budget: str | None = setting(None, "str", choices=DENSIFY_BUDGETS, nullable=True)
    per_keyframe: int | None = setting(None, "int", lo=0, nullable=True)  # budget=constant: seeds per keyframe
    final_count: int | None = setting(None, "int", lo=1, nullable=True)  # budget=taming: the curve's end size
    final_keyframe: int | None = setting(None, "int", lo=1, nullable=True)  # budget=taming: ... reached here
    # which candidate pixels become seeds when fewer fit (budget or cap): "random" = a uniform sample drawn
    # from the run's seed (the densification generator); "need" = the largest silhouette deficit 1 - alpha
    # first, then the largest depth error, then the lower pixel index (row-major)
    seed_order: str = setting("random", "str", choices=SEED_ORDERS)

    def __post_init__(self) -> None:
        check_rules(self, "slam.densify.")
        needs = {"constant": ("per_keyframe",), "taming": ("final_count", "final_keyframe")}
        for key in needs.get(self.budget or "", ()):
            if getattr(self, key) is None:
                raise ConfigError(
                    f"slam.densify.{key}: expected an integer with slam.densify.budget={self.budget}, found null"
                )


@dataclass
class SlamConfig:
    """Backend hyperparameters; the paper's values where it gives them."""

    # from the flow + PnP start, sized for a CPU; the paper's 50: slam=paper
    tracking_iters: int = setting(20, "int", lo=1)
    # the second frame has no constant-velocity guess (it starts at the first pose), and Adam's
    # step bounds how far a pose can travel: ~0.4 x lr x iterations over the decayed schedule
    tracking_iters_first: int = setting(100, "int", lo=1)
    tracking_lr_trans: float = 5e-2  # Adam step on the twist's translation part (m), decayed ...
    tracking_lr_rot: float = 4e-3  # ... and rotation part (rad)
    tracking_lr_final: float = 0.1  # ... exponentially to this fraction over the iterations
    lambda_depth_track: float = 1.0  # paper
    lambda_depth_map: float = 1.5  # paper
    # mapping's colour term: (1 - w) x L1 + w x D-SSIM, the 3DGS / SplaTAM form (both use 0.2); 0 = L1 alone
    lambda_ssim_map: float = setting(0.0, "float", lo=0.0, hi=1.0)
    silhouette_min: float = 0.99  # tracking uses pixels the map explains with confidence
    # ... and, when > 0, only those whose depth error is within this x the median error of those pixels, so that
    # a few pixels the map cannot explain (a car that moved on) do not steer the pose: SplaTAM's
    # ignore_outlier_depth_loss at 10 (see _depth_inliers); 0 = off. It does not remove the pull that
    # feature_weight holds (reports/fidelity/README.md, "At the faithful preset")
    tracking_depth_outlier: float = setting(0.0, "float", lo=1.0, lo_open=True, also=(0.0,))
    # which pixels tracking compares: "current" re-selects the confident ones at every iterate;
    # "init" fixes them at the initial pose (which falls short when the initial pose is far off).
    tracking_mask: str = setting("current", "str", choices=TRACKING_MASKS)
    # where tracking starts: "velocity" extrapolates the last motion; "flow_pnp" (default) refines
    # that prediction with corners tracked since the previous frame and PnP on its depth
    # (bench/slam/frontend.py), falling back to "velocity" when too few corners survive. Why: see
    # reports/known_limits.md (the velocity guess alone is lost on longer drives).
    tracking_init: str = setting("flow_pnp", "str", choices=TRACKING_INITS)
    flow_pnp: FlowPnpConfig = field(default_factory=FlowPnpConfig)  # slam.flow_pnp.NAME=VALUE
    # tracking loss + this x the mean reprojection error (px, L1) of the corners flow + PnP matched (its
    # RANSAC inliers, 3-D from the previous frame's depth); 0 = off. Why: the depth term of the photometric
    # loss follows the map's geometry, which stereo depth leaves wrong on foliage and far facades, and on a
    # straight road it pulls the pose back along the optical axis; the corners hold the scale there. The
    # released LSG-SLAM code adds a feature-warping term for the same reason (use_warp_loss, weight_warp=10);
    # this term is ours, in pixels, not theirs. On (2) with dataset=kitti in every preset
    # (bench/conf/slam_dataset/kitti.yaml).
    feature_weight: float = setting(0.0, "float", lo=0.0)
    depth_loss_max_m: float = 30.0  # far pixels (sky, distant road) only constrain colour
    depth_far_m: float | None = 60.0  # Gaussians beyond this add no depth (see rasterize); None = all do
    depth_normalized: bool = False  # compare depth / silhouette (unbiased where coverage < 1)
    # compositing backend (bench/slam/raster.py): auto = the compiled "fused" kernels on CPU; on CUDA
    # "gsplat" where it is installed (bench/slam/raster_gsplat.py), else the "torch" reference
    raster_backend: str = setting("auto", "str", choices=BACKENDS)
    # Mip-Splatting's 2D filter (gsplat's rasterize_mode="antialiased"): each opacity scaled by
    # sqrt(det S / det(S + 0.3 I)) so a Gaussian fitted in a near view keeps its integral, not a 0.3 px
    # blob at full opacity, in farther views (bench/slam/raster.py:antialias_compensation). Off = the
    # paper's base system (SplaTAM's rasterizer has only the low-pass).
    raster_antialias: bool = False
    # how the gsplat backend computes the per-Gaussian statistics (coverage, hit count, max weight) the pruning
    # criteria read: torch = bench/slam/raster_gsplat.py:pair_stats, chunks of whole tiles (many small kernels a
    # frame, reports/gpu); triton = bench/slam/gsplat_stats.py, one kernel; auto = triton where
    # it is importable. The same figures to float rounding (tests/slam/test_raster_gsplat.py); CPU backends ignore it
    gsplat_stats: str = setting("auto", "str", choices=("auto", "torch", "triton"))
    # one scale per Gaussian, as SplaTAM's (gaussian_distribution="isotropic"), the paper's base system;
    # False = 3DGS's anisotropic ellipsoids. Rendered with the mean of the three log-scales, which get
    # equal gradients and so stay equal (the map file keeps three columns either way). Why: a needle
    # fitted to one view is wrong from the next; a sphere is the same from every view.
    isotropic: bool = False
    mapping_iters: int = setting(100, "int", lo=0)  # paper: 100 per keyframe
    # keep fitting past mapping_iters, mapping_fit_step iterations at a time, while the new keyframe's own render
    # scores below this PSNR over its pixels with observed depth (keyframes.csv kf_psnr_depth_db, the same
    # figure), up to mapping_fit_max_iters in all; None = exactly mapping_iters (the paper). Why: a fixed count
    # is set by the slowest view, and pays it on every keyframe; this pays it on the slow ones only (figures in
    # reports/fidelity/README.md). The iterations each keyframe got are keyframes.csv kf_map_iters.
    mapping_fit_psnr_db: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)
    mapping_fit_step: int = setting(25, "int", lo=1)
    mapping_fit_max_iters: int = setting(300, "int", lo=0)
    # when keyframes get those iterations: "keyframes" = every keyframe (the paper's text); "first" = the
    # first keyframe only, later keyframes only densify (and prune), as the released Pocket-SLAM code
    # does (`if time_idx < 1` around its mapping loop; +experiment=released)
    mapping_schedule: str = setting("keyframes", "str", choices=MAPPING_SCHEDULES)
    mapping_fresh_optimizer: bool = True  # new Adam moments per keyframe, as SplaTAM does
    # torch's fused Adam for the map (one pass over each parameter tensor, where the per-op implementation makes
    # about ten); False = that per-op implementation, as every run before it. The two compute the same update and
    # differ at float rounding (speed and effect: reports/speed/2026-11-29-whole-run.md)
    adam_fused: bool = True
    # keyframes optimised together (current one included); None = all. A short window lets later
    # close-ups overwrite the views of the early drive (figures in reports/known_limits.md).
    mapping_window: int | None = setting(None, "int", lo=1, nullable=True)
    # which keyframe of the window each mapping iteration fits: "alternate" = the newest at every even
    # iteration, a random other one at every odd one (half the iterations go to the newest); "uniform" = a
    # random one of the window, the newest included, as SplaTAM's mapping loop draws (scripts/splatam.py:
    # rand_idx = np.random.randint(0, len(selected_keyframes)), the current frame one of them). Why an
    # option: it is a difference from the paper's base system, and its effect on the fit differs between
    # exact and stereo depth (measured in reports/fidelity/README.md)
    mapping_draw: str = setting("alternate", "str", choices=MAPPING_DRAWS)
    # iterations over all keyframes once the drive is over (Mapping.refine), timed apart from the
    # SLAM loop and not in fps; 0 = evaluate the map exactly as mapping left it
    refine_iters: int = setting(0, "int", lo=0)
    # every learning rate of the final refinement decays exponentially from its mapping value to this fraction
    # of it at the last iteration; 1 = constant (as mapping). Why: at a constant rate each step fits the one view
    # drawn, and the map hovers at that noise instead of settling between the views (3DGS decays its position
    # rate over training for the same reason). Mapping's rates are restored after the refinement.
    refine_lr_final: float = setting(1.0, "float", lo=0.0, hi=1.0, lo_open=True)
    kf_every: int = setting(3, "int", lo=1)  # a keyframe at least every N frames
    kf_min_trans_m: float = 3.0  # ... or once the camera moved this far since the last one
    kf_min_rot_deg: float = 15.0  # ... or turned this much
    # how the keyframe store holds keyframes: precision, a window of the K newest, memory or disk
    # (bench/slam/keyframes.py; slam.keyframes.NAME=VALUE)
    keyframes: KeyframeStoreConfig = field(default_factory=KeyframeStoreConfig)
    # Densification (new Gaussians on a keyframe). The defaults re-seed far more eagerly than
    # SplaTAM; conf/slam/splatam.yaml holds SplaTAM's rule (silhouette < 0.5, no colour rule,
    # every pixel, opacity 0.5, 1 px seeds). After pruning, the eager rule refills the holes.
    densify_stride: int = setting(2, "int", lo=1)  # new Gaussians from every N-th pixel in each direction (SplaTAM: 1)
    densify_silhouette: float = 0.95  # add where the rendered silhouette is below this (SplaTAM: 0.5)
    densify_depth_err_mult: float = 50.0  # ... or where depth error > mult x median error (SplaTAM)
    # the median of that rule over: "confident" pixels (valid depth, silhouette > silhouette_min), or
    # the whole "image" with pixels of no depth counting 0 (SplaTAM's depth_error.median())
    densify_err_median: str = setting("confident", "str", choices=DENSIFY_ERR_MEDIANS)
    densify_color_err: float = 0.15  # ... or where mean-RGB L1 error exceeds this (detail seen closer); <= 0 off
    # seed sigma in pixels at the seed's depth (scale = depth x sigma_px / fx); None = 0.5 x stride + 0.25,
    # so neighbouring seeds overlap at about one sigma. SplaTAM: 1 (scale = depth / focal)
    densify_sigma_px: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)
    # opaque seeds: tracking needs a confident silhouette early (SplaTAM: 0.5)
    init_opacity: float = setting(0.95, "float", lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    densify: DensifyConfig = field(default_factory=DensifyConfig)  # slam.densify.NAME=VALUE: cap and budget
    name: str = "default"  # the preset's name (conf/slam/NAME.yaml), recorded as slam_preset in metrics.json
    max_depth_m: float = 150.0  # observed depth beyond this is ignored
    lrs: LearningRates = field(default_factory=LearningRates)  # slam.lrs.NAME=VALUE
    # which Gaussians wait on disk while the camera is far from them (bench/slam/residency.py); off = none
    residency: ResidencyConfig = field(default_factory=ResidencyConfig)  # slam.residency.NAME=VALUE
    # what declares tracking lost (besides a non-finite pose and a collapsed silhouette), for lost_patience
    # consecutive frames: "depth" = the depth L1 on confidently mapped pixels (those tracking uses, nearer than
    # depth_loss_max_m) above lost_depth_ratio x its median over the last lost_baseline_frames frames that were
    # not flagged (from the 4th tracked frame on), and above lost_depth_floor_m; "color" = the mean colour L1
    # on those pixels above lost_residual; "both" = either flags the frame; "off" = neither (both readings are
    # still logged in track_log). Why both: a pose a metre off can leave the colour L1 within the range of good
    # frames (road and facades look alike a metre over) while the depth L1 grows, so the depth check catches
    # the metre; but its baseline follows a map whose error grows (slam=splatam's stalls), and there the
    # colour check is the one that catches a gross loss. The runs behind this: reports/lost_detector/README.md
    # The default stays the colour check: the depth check can also flag a frame at the true pose that shows
    # unmapped street (tests/slam/test_system.py), so it is opt-in until its threshold holds.
    lost_check: str = setting("color", "str", choices=LOST_CHECKS)
    lost_depth_ratio: float = setting(3.0, "float", lo=1.0, lo_open=True)
    lost_depth_floor_m: float = setting(0.3, "float", lo=0.0)
    lost_baseline_frames: int = setting(20, "int", lo=1)
    lost_residual: float = 0.25  # lost_check=color: mean colour L1 on tracked pixels that counts as failure ...
    lost_patience: int = setting(3, "int", lo=1)  # ... for this many consecutive frames (either check)
    lost_min_silhouette_frac: float = 0.05  # fewer confidently mapped pixels than this = collapsed
    seed: int = 0

    def __post_init__(self) -> None:
        check_rules(self, "slam.")
        # a mapping of overrides (SlamConfig(lrs={"colors": 0.5}) from Python) becomes the typed group
        self.lrs = as_config(LearningRates, self.lrs, "slam.lrs")
        self.flow_pnp = as_config(FlowPnpConfig, self.flow_pnp, "slam.flow_pnp")
        self.densify = as_config(DensifyConfig, self.densify, "slam.densify")
        self.keyframes = as_config(KeyframeStoreConfig, self.keyframes, "slam.keyframes")
        self.residency = as_config(ResidencyConfig, self.residency, "slam.residency")
        if self.mapping_fit_psnr_db is not None and self.mapping_fit_max_iters < self.mapping_iters:
            raise ConfigError(
                f"slam.mapping_fit_max_iters: expected at least slam.mapping_iters ({self.mapping_iters}) "
                f"when slam.mapping_fit_psnr_db is set, found {self.mapping_fit_max_iters}"
            )
