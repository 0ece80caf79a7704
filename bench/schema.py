"""The run directory's format: every field of ``metrics.json`` and ``keyframes.csv``, with its unit.

The writer (``bench.run.lifecycle``), the report reader (``bench.report``) and the docs' run-directory tables
(``docs/run-directory.md``) all follow this module; ``tests/test_schema.py`` checks that page against
``markdown()``. Regenerate its block from what ``python -m bench.schema`` prints.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

METRICS_FILE = "metrics.json"
KEYFRAMES_FILE = "keyframes.csv"
MILESTONES_FILE = "milestones.csv"
REFINE_CURVE_FILE = "refine_curve.csv"
MIB = float(2**20)  # bytes per MiB: every *_mib figure

STATUSES: tuple[str, ...] = ("ok", "lost", "failed", "interrupted", "running")
FINISHED: tuple[str, ...] = ("ok", "lost")  # a rerun of the same config skips these
UNFINISHED: tuple[str, ...] = ("running", "interrupted")  # left out of tables and plots
# where a redo of a finished run works (its record, checkpoints and files) until it finishes too;
# only then do its files replace the finished run's (bench.run.record.promote)
REDO_DIR = ".redo"


@dataclass(frozen=True)
class Field:
    name: str
    unit: str  # "" for counts, names and flags
    holds: str
    kind: str = "number"  # number | text | object (a dict or list kept as is)


RUN_FIELDS: tuple[Field, ...] = (
    Field("strategy", "", "strategy name (`none` without `+strategy`)", "text"),
    Field("dataset", "", "dataset name", "text"),
    Field("seq", "", "sequence as written, or the dataset's default; null only if it has none", "text"),
    Field("seed", "", "run seed"),
    Field(
        "keep_ratio",
        "",
        "`prune.keep_ratio` given to the strategy; null without `+strategy` or with `prune.target=absolute`",
    ),
    Field("slam_preset", "", "`slam.name`, the backend preset (runs of different presets never pool)", "text"),
    Field("config_hash", "", "hash of the resolved config (what resume compares)", "text"),
    Field("code_version", "", "commit, code-tree hash, dirty flag, diff hash (resume ignores the commit)", "object"),
    Field("inputs", "", "input-file fingerprint: text and image files by content (not mtime)", "object"),
)

KEYFRAME_FIELDS: tuple[Field, ...] = (
    Field("kf", "", "keyframe index"),
    Field("frame", "", "frame index of the keyframe"),
    Field("n_gaussians", "", "Gaussians after pruning"),
    Field("n_masked", "", "Gaussians kept in memory but hidden from rendering"),
    Field("n_added", "", "Gaussians added by this keyframe's mapping"),
    Field(
        "n_densify_dropped",
        "",
        "candidate seeds this keyframe's densification left out for its budget and the cap (`slam.densify`)",
    ),
    Field(
        "n_cap_removed",
        "",
        "Gaussians removed before this keyframe's seeds to hold the map at `slam.densify.cap`, lowest "
        "strategy score first (not in `n_pruned`)",
    ),
    Field("n_pruned", "", "Gaussians removed by the strategy (with `prune.every=frame`: since the last keyframe)"),
    Field("n_candidates", "", "Gaussians the strategy could prune (in view, not new), over those prune calls"),
    Field(
        "n_evicted",
        "",
        "Gaussians on disk at the window's end (`slam.residency`; not in `n_gaussians` and in no render); "
        "0 with the policy off",
    ),
    Field("n_restored", "", "Gaussians `slam.residency` brought back from disk at this keyframe, before densifying"),
    Field("n_kf_held", "", "keyframes the store holds at the window's end (in memory or on disk)"),
    Field("state_bytes", "B", "exact bytes of Gaussian state: params, grads, Adam moments, strategy state"),
    Field("state_mib", "MiB", "`state_bytes` in MiB"),
    Field("cpu_rss_peak_mib", "MiB", "process peak RSS in the window (VmHWM, or sampled)"),
    Field("torch_live_peak_mib", "MiB", "peak bytes of live torch CPU tensors in the window; null on CUDA"),
    Field("cuda_alloc_peak_mib", "MiB", "CUDA allocator peak (allocated) in the window; null on CPU"),
    Field("cuda_reserved_peak_mib", "MiB", "CUDA allocator peak (reserved) in the window; null on CPU"),
    Field("track_s", "s", "tracking time of the keyframe's frame"),
    Field("map_s", "s", "mapping time"),
    Field("prune_s", "s", "pruning time"),
    # the headline peak split into parts (bench/run/loop.py:memory_parts); mem_state + mem_keyframes + mem_other +
    # mem_work = the peak column (cuda_alloc_peak_mib on CUDA, torch_live_peak_mib on CPU), to rounding
    Field(
        "mem_state_mib",
        "MiB",
        "Gaussian state at its largest in the window (after densification, during "
        "mapping): params, a gradient per param, Adam moments, strategy state; exact bytes",
    ),
    Field(
        "mem_keyframes_mib",
        "MiB",
        "keyframe store live in memory: each held keyframe's colour and depth at their stored dtype "
        "(`slam.keyframes.precision`; none for a keyframe on disk) and its pose; exact bytes",
    ),
    Field(
        "mem_other_mib",
        "MiB",
        "other tensors still live at the window's end (current frame, previous frame for "
        "the front-end, pixel grid, ...): live bytes then, minus state and keyframes then",
    ),
    Field(
        "mem_work_mib",
        "MiB",
        "transient work buffers at the peak (render outputs, rasterizer buffers, autograd "
        "saved tensors): the peak minus the three parts above",
    ),
    # files the run holds on disk at the window's end (bench/run/loop.py:disk_parts); not in any peak above
    Field(
        "disk_state_mib",
        "MiB",
        "Gaussian state written to disk (map residency) at the window's end; exact bytes of its files",
    ),
    Field(
        "disk_keyframes_mib",
        "MiB",
        "keyframe store on disk (`slam.keyframes.residency=disk`) at the window's end; exact bytes of its files",
    ),
    Field("disk_total_mib", "MiB", "`disk_state_mib` + `disk_keyframes_mib`"),
    # what pruning saw, removed, and what came back; counts over the window's prune calls, quartiles of the last
    Field("cand_cov_q1", "px", "candidates' coverage C_i at the pruning pose, first quartile"),
    Field("cand_cov_q2", "px", "... median"),
    Field("cand_cov_q3", "px", "... third quartile"),
    Field("cand_w_q1", "", "candidates' max blending weight (alpha x T) at the pruning pose, first quartile"),
    Field("cand_w_q2", "", "... median"),
    Field("cand_w_q3", "", "... third quartile"),
    Field("n_redundant", "", "candidates whose max blending weight at the pruning pose is <= 0.05 (redundant)"),
    Field("n_pruned_redundant", "", "of those, the ones the strategy pruned"),
    Field(
        "n_hole_px",
        "",
        "pixels the prune pushed below the densification silhouette `slam.densify_silhouette` "
        "at the pruning pose (holes)",
    ),
    Field(
        "n_reseeded_holes",
        "",
        "Gaussians this keyframe seeded in pixels the prunes since the previous "
        "keyframe opened (their surface points, from the observed depth, projected into this view)",
    ),
    Field(
        "n_score_views",
        "",
        "views the keyframe's prune rendered to score the map (`PruneContext.render_views`; "
        "the criteria with `score_views`); null for a strategy that scores from the pruning render alone",
    ),
    Field("score_views", "", "their keyframe indices, as ranges (`0-3;5`); null as above", "text"),
    Field("diag_s", "s", "time spent on the pruning diagnostics above (included in `prune_s`)"),
    # how well mapping fitted the keyframe it just mapped (bench/slam/prune_diagnostics.py:_fit_diagnostics)
    Field("kf_psnr_db", "dB", "the keyframe's own render right after its mapping, before pruning: PSNR, whole image"),
    Field("kf_psnr_depth_db", "dB", "... PSNR over the pixels with observed depth (those a map can seed)"),
    Field("kf_psnr_nodepth_db", "dB", "... PSNR over the pixels without depth (sky, no disparity); null if none"),
    Field("kf_depth_frac", "", "share of the keyframe's pixels with observed depth"),
    Field(
        "kf_map_iters",
        "",
        "mapping iterations the keyframe got: `slam.mapping_iters`, more under `slam.mapping_fit_psnr_db`",
    ),
    # the tracked path against the true one (bench/metrics/trajectory.py:window_path_ratios), so a drift shows
    # where it starts; null without ground truth
    Field("path_length_m", "m", "ground-truth path length from the previous keyframe's frame to this one's"),
    Field(
        "path_length_ratio",
        "",
        "estimated / ground-truth path length over that window, unaligned; null for keyframe 0 and a still camera",
    ),
    Field(
        "path_length_ratio_prefix",
        "",
        "... over every frame so far (what metrics.json's `path_length_ratio` would read had the run ended here)",
    ),
)
PATH_WINDOW_COLUMNS: tuple[str, ...] = ("path_length_m", "path_length_ratio", "path_length_ratio_prefix")
FIT_COLUMNS: tuple[str, ...] = ("kf_psnr_db", "kf_psnr_depth_db", "kf_psnr_nodepth_db", "kf_depth_frac")
# a row's image metrics: the map as it was when the row was taken, under eval.protocol
_ROW_IMAGE_FIELDS: tuple[Field, ...] = (
    Field("psnr_db", "dB", "PSNR of the map as it was then (`eval.protocol`), on every `eval.every`-th frame so far"),
    Field("ssim", "", "... SSIM"),
    Field("ms_ssim", "", "... MS-SSIM (null for images under 176 px on a side)"),
    Field("lpips", "", "... LPIPS (null without local AlexNet weights)"),
    Field("eval_frames", "", "frames rendered for the row"),
)
ROW_IMAGE_COLUMNS: tuple[str, ...] = tuple(f.name for f in _ROW_IMAGE_FIELDS)
MILESTONE_FIELDS: tuple[Field, ...] = (
    Field("frames", "", "frames tracked when the row was taken (an `eval.at_frames` entry)"),
    Field("path_length_m", "m", "ground-truth path length over those frames"),
    Field("path_length_ratio", "", "estimated / ground-truth path length over those frames, unaligned"),
    Field("ate_rmse_m", "m", "ATE RMSE over those frames (`eval.ate_align`): what a drive this long scores"),
    *_ROW_IMAGE_FIELDS,
    Field("n_gaussians", "", "Gaussians in memory then"),
    Field("n_evicted", "", "Gaussians map residency held on disk then; the row's image metrics render them too"),
    Field("state_mib", "MiB", "Gaussian state then (params, grads, Adam moments, strategy state)"),
    Field("peak_mem_mib", "MiB", "the headline peak over the keyframe windows so far (as `peak_mem_mib`)"),
    Field("eval_s", "s", "time the row took (not SLAM time)"),
)
MILESTONE_COLUMNS: list[str] = [f.name for f in MILESTONE_FIELDS]
REFINE_CURVE_FIELDS: tuple[Field, ...] = (
    Field("refine_iters", "", "refinement iterations done when the row was taken (an `eval.at_refine_iters` entry)"),
    Field("refine_s", "s", "refinement time to then, the rows' own time excluded (as the run's `refine_s`)"),
    *_ROW_IMAGE_FIELDS,
    Field("eval_s", "s", "time the row took (not refinement time)"),
)
REFINE_CURVE_COLUMNS: list[str] = [f.name for f in REFINE_CURVE_FIELDS]
MEMORY_PART_COLUMNS: tuple[str, ...] = ("mem_state_mib", "mem_keyframes_mib", "mem_other_mib", "mem_work_mib")
DISK_PART_COLUMNS: tuple[str, ...] = ("disk_state_mib", "disk_keyframes_mib", "disk_total_mib")
DISK_PEAK_FIELD = "disk_peak_mib"
PRUNE_COUNT_COLUMNS: tuple[str, ...] = ("n_redundant", "n_pruned_redundant", "n_hole_px", "n_reseeded_holes")
DENSIFY_COUNT_COLUMNS: tuple[str, ...] = ("n_densify_dropped", "n_cap_removed")  # per keyframe, from diag
SCORE_VIEW_COLUMNS: tuple[str, ...] = ("n_score_views", "score_views")
PRUNE_QUARTILE_COLUMNS: tuple[str, ...] = (
    "cand_cov_q1", "cand_cov_q2", "cand_cov_q3", "cand_w_q1", "cand_w_q2", "cand_w_q3",
)  # fmt: skip
KEYFRAME_COLUMNS: list[str] = [f.name for f in KEYFRAME_FIELDS]

# The headline memory figure and where it comes from, by preference: what the device must hold at
# once (the paper reads the CUDA allocator peak), else torch's live tensors, else the process RSS.
PEAK_FIELD = "peak_mem_mib"
PEAK_SOURCE_FIELD = "peak_mem_source"
PEAK_SOURCES: dict[str, str] = {
    "cuda_alloc": "cuda_alloc_peak_mib",
    "torch_live": "torch_live_peak_mib",
    "cpu_rss": "cpu_rss_peak_mib",
}
MEMORY_PEAK_COLUMNS: tuple[str, ...] = (
    "cpu_rss_peak_mib", "torch_live_peak_mib", "cuda_alloc_peak_mib", "cuda_reserved_peak_mib",
)  # fmt: skip

METRIC_FIELDS: tuple[Field, ...] = (
    Field("ate_rmse_m", "m", "ATE RMSE, translation part, after `ate_alignment` (evo APE)"),
    Field("ate_mean_m", "m", "ATE mean"),
    Field("ate_max_m", "m", "ATE max"),
    Field("ate_alignment", "", "`se3`, `sim3` or `none`", "text"),
    Field("ate_num_poses", "", "associated poses the ATE is over"),
    Field("ate_max_diff_s", "s", "timestamp association window"),
    Field("ate_first_frame", "", "first tracked frame the ATE is over (position among tracked frames)"),
    Field("ate_last_frame", "", "last tracked frame the ATE is over (inclusive)"),
    Field("path_length_m", "m", "ground-truth path length over the tracked frames"),
    Field(
        "path_length_ratio",
        "",
        "estimated path length / ground-truth path length over the tracked frames, "
        "unaligned: below 1, the tracker lost scale and came out short",
    ),
    Field("rpe_trans_rmse_m", "m", "RPE translation RMSE (`eval.rpe=true`)"),
    Field("rpe_rot_rmse_deg", "deg", "RPE rotation RMSE (`eval.rpe=true`)"),
    Field("rpe_delta_frames", "", "RPE step"),
    Field(
        "psnr_db",
        "dB",
        "PSNR of frames rendered from the final map at the estimated poses, scored under `eval_protocol`",
    ),
    Field("ssim", "", "SSIM (11 px Gaussian window), same frames and protocol"),
    Field(
        "ms_ssim",
        "",
        "MS-SSIM (5 scales; what the paper's base system reports as SSIM), same frames and "
        "protocol; null for images under 176 px on a side",
    ),
    Field("lpips", "", "LPIPS (AlexNet), same frames and protocol; null without local weights"),
    Field(
        "eval_protocol",
        "",
        "`eval.protocol` the image metrics were scored under: `full` (the whole image), "
        "`splatam` (valid-depth mask), `released` (rendered silhouette > 0.5); absent in runs before it existed, "
        "which were `full`",
        "text",
    ),
    Field(
        "eval_mask_frac",
        "",
        "share of the pixels the protocol's mask kept, mean over the evaluated frames (masked protocols only)",
    ),
    Field(
        "eval_depth_range_m",
        "m",
        "[near, far] of the `splatam` mask (`dataset.eval_depth_near_m`, `dataset.eval_depth_far_m`; far null: none)",
        "object",
    ),
    Field("eval_frames", "", "frames the image metrics are over (`eval.every`)"),
    Field("fps", "1/s", "frames / SLAM-loop wall time, warm-up frames excluded"),
    Field(
        "fps_slam",
        "1/s",
        "frames / (tracking + mapping s), the paper's released code's FPS: pruning and residency count as mapping; "
        "frame loading, stereo depth and loop bookkeeping do not; warm-up frames included",
    ),
    Field("slam_wall_s", "s", "SLAM-loop wall time after the warm-up frames"),
    Field("warmup_s", "s", "the warm-up frames' time (`warmup_frames`), left out of `slam_wall_s` and `fps`"),
    Field("refine_s", "s", "final refinement time (not in `fps`)"),
    Field("phase_s", "s", "time per phase of the frame loop (tracking, mapping, pruning), warm-up included", "object"),
    Field("eval_s", "s", "evaluation time: ATE, rendering, PSNR/SSIM/LPIPS"),
    Field("wall_s", "s", "the whole run, from loading to figures"),
    Field("num_frames", "", "frames tracked"),
    Field("keep_ratio", "", "as `run.keep_ratio` (null when nothing is pruned or the target is absolute)"),
    Field("num_keyframes", "", "keyframe windows (rows of keyframes.csv)"),
    Field(
        "tracking_velocity_starts",
        "",
        "tracked frames whose start was the constant-velocity guess: `slam.tracking_init=velocity`, or flow + "
        "PnP found too few corners (`slam.flow_pnp.min_inliers`), so the feature term had none to hold",
    ),
    Field("gaussians_final", "", "Gaussians in the final map"),
    Field("gaussians_peak", "", "largest `n_gaussians` over the windows and at the end (after the last keyframe)"),
    Field("gaussians_added_total", "", "sum of `n_added`: with the totals below, whether pruning shrank the map"),
    Field("gaussians_pruned_total", "", "sum of `n_pruned`"),
    Field("prune_candidates_total", "", "sum of `n_candidates`"),
    Field("state_peak_mib", "MiB", "largest `state_mib`"),
    # the regime: how densely the map grows, and what pruning can reach (bench.schema.regime_summary)
    Field(
        "gaussians_added_per_kf_mpx",
        "",
        "`gaussians_added_total` / `num_keyframes` / megapixels of the run's images: how densely the map grows",
    ),
    Field(
        "state_per_gaussian_bytes",
        "B",
        "Gaussian state (params, grads, Adam moments, strategy state) per Gaussian, at the largest map",
    ),
    Field(
        "store_per_keyframe_bytes",
        "B",
        "keyframe store bytes in memory per keyframe held, at the last keyframe window",
    ),
    Field(
        "gaussian_share_of_peak",
        "",
        "(`mem_state_mib` + `mem_work_mib`) / the peak, at the keyframe window of largest peak: the part "
        "that follows the Gaussians, every work buffer counted as following them (an upper bound); one minus "
        "it bounds from below what no pruning can save there. Null where the memory parts are",
    ),
    Field("cpu_rss_peak_mib", "MiB", "largest window value of the column of that name"),
    Field("torch_live_peak_mib", "MiB", "largest window value of the column of that name"),
    Field("cuda_alloc_peak_mib", "MiB", "largest window value of the column of that name"),
    Field("cuda_reserved_peak_mib", "MiB", "largest window value of the column of that name"),
    Field(
        PEAK_FIELD,
        "MiB",
        "the headline peak: the column named by `peak_mem_source`. It counts what is live in memory: the CUDA "
        "allocator on the device on CUDA, torch's live tensors on CPU (the process RSS only where neither is "
        "measured). Files on disk (`disk_peak_mib`) are not in it",
    ),
    Field(PEAK_SOURCE_FIELD, "", f"`{'`, `'.join(PEAK_SOURCES)}`: the first available on the device", "text"),
    Field(
        "memory_method",
        "",
        "how the peaks were measured (`cpu_rss`, `torch_live`; `malloc`: the `memory.malloc` policy that held)",
        "object",
    ),
    Field(
        DISK_PEAK_FIELD,
        "MiB",
        "largest `disk_total_mib` over the windows: the run's files on disk (keyframe store, map residency); "
        "not in `peak_mem_mib`",
    ),
)
METRIC_NAMES: tuple[str, ...] = tuple(f.name for f in METRIC_FIELDS)
REGIME_FIELDS: tuple[str, ...] = (
    "gaussians_added_per_kf_mpx", "state_per_gaussian_bytes", "store_per_keyframe_bytes", "gaussian_share_of_peak",
)  # fmt: skip
NUMERIC_METRICS: frozenset[str] = frozenset(f.name for f in METRIC_FIELDS if f.kind == "number")


def memory_summary(windows: Sequence[dict[str, Any]], device_type: str) -> dict[str, Any]:
    """Per-run peaks over the keyframe windows, plus the headline ``peak_mem_mib`` and its source."""

    def peak(key: str) -> float | None:
        vals = [w[key] for w in windows if w.get(key) is not None]
        return max(vals) if vals else None

    summary: dict[str, Any] = {
        "gaussians_peak": peak("n_gaussians") or 0,
        "state_peak_mib": peak("state_mib"),
        **{key: peak(key) for key in MEMORY_PEAK_COLUMNS},
        DISK_PEAK_FIELD: peak("disk_total_mib"),
    }
    sources = list(PEAK_SOURCES) if device_type == "cuda" else [s for s in PEAK_SOURCES if s != "cuda_alloc"]
    source = next((s for s in sources if summary[PEAK_SOURCES[s]] is not None), sources[0])
    summary[PEAK_FIELD], summary[PEAK_SOURCE_FIELD] = summary[PEAK_SOURCES[source]], source
    return summary


def regime_summary(windows: Sequence[dict[str, Any]], image_hw: tuple[int, int], peak_source: Any) -> dict[str, Any]:
    """The run's regime descriptors (``metrics.json``) from its keyframes.csv rows and image size (H, W)."""
    mpx = image_hw[0] * image_hw[1] / 1e6
    out: dict[str, Any] = dict.fromkeys(REGIME_FIELDS)
    if not windows:
        return out
    out["gaussians_added_per_kf_mpx"] = round(sum(w["n_added"] for w in windows) / len(windows) / mpx, 1)
    largest = max(windows, key=lambda w: w["n_gaussians"])
    if largest["n_gaussians"]:
        out["state_per_gaussian_bytes"] = round(largest["state_bytes"] / largest["n_gaussians"], 1)
    # the store per keyframe at the last window that measured it: exact bytes, the same in a resumed run
    held = [w for w in windows if w.get("mem_keyframes_mib") is not None and w.get("n_kf_held")]
    if held:
        out["store_per_keyframe_bytes"] = round(held[-1]["mem_keyframes_mib"] * MIB / held[-1]["n_kf_held"], 1)
    col = peak_column(peak_source)
    if col is None:
        return out
    at_peak = [w for w in windows if w.get(col) is not None]
    if not at_peak:
        return out
    w = max(at_peak, key=lambda r: r[col])
    if w.get("mem_state_mib") is not None and w.get("mem_work_mib") is not None and w[col] > 0:
        out["gaussian_share_of_peak"] = round((w["mem_state_mib"] + w["mem_work_mib"]) / w[col], 4)
    return out


def peak_column(source: Any) -> str | None:
    """The keyframes.csv column behind the headline figure of a run whose source is ``source``."""
    return PEAK_SOURCES.get(source) if isinstance(source, str) else None


def _table(fields: Sequence[Field]) -> list[str]:
    rows = ["| field | unit | holds |", "|---|---|---|"]
    rows += [f"| `{f.name}` | {f.unit or '-'} | {f.holds} |" for f in fields]
    return rows


def markdown() -> str:
    """The run-directory field tables of ``docs/run-directory.md``, generated from this module."""
    lines = [
        f"`{METRICS_FILE}` `run` block:",
        "",
        *_table(RUN_FIELDS),
        "",
        f"`{METRICS_FILE}` `metrics` block (fields a run could not compute are null or absent):",
        "",
        *_table(METRIC_FIELDS),
        "",
        f"`{KEYFRAMES_FILE}`, one row per keyframe window (frames since the previous keyframe, its mapping and"
        " pruning); memory columns are null where the probe cannot measure on this device:",
        "",
        *_table(KEYFRAME_FIELDS),
        "",
        f"`{MILESTONES_FILE}`, one row per `eval.at_frames` entry reached (absent without it):",
        "",
        *_table(MILESTONE_FIELDS),
        "",
        f"`{REFINE_CURVE_FILE}`, one row per `eval.at_refine_iters` entry (absent without it):",
        "",
        *_table(REFINE_CURVE_FIELDS),
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown())
