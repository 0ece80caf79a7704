"""Bad input as a user makes it, through the CLI: exit code, the single ``error:`` line, what is on disk.

Settings are refused before Hydra creates a run dir (nothing on disk); bad dataset files are found
when the data is opened, before any SLAM work (a ``failed`` record). The CLI runs in-process here:
a fail-before-work case costs a config composition, not a Python start. Stopped and mid-run cases
(signals, a corrupt frame) are in ``test_stopped_runs.py``.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from bench.cli import entry as cli

REPO = Path(__file__).resolve().parents[1]


@dataclass
class Outcome:
    code: int
    stderr: str
    stdout: str

    @property
    def error_line(self) -> str:
        lines = [ln for ln in self.stderr.splitlines() if ln.startswith("error:")]
        assert len(lines) == 1, self.stderr
        assert "Traceback" not in self.stderr, self.stderr
        return lines[0]


def run_cli(args: list[str]) -> Outcome:
    """``python -m bench ARGS`` in this process: exit code, stderr, stdout."""
    out, err = io.StringIO(), io.StringIO()
    argv = sys.argv
    sys.argv = ["bench", *args]
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                code = cli.main()
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 1
    finally:
        sys.argv = argv
    return Outcome(code, err.getvalue(), out.getvalue())


def tiny(args: list[str]) -> list[str]:
    """``+experiment=tiny`` where it applies: it sizes the synthetic scene, which a real dataset has not."""
    real = any(a.startswith("dataset=") and a != "dataset=synthetic" for a in args)
    return [] if real else ["+experiment=tiny"]


# --------------------------------------------------------------------------- settings
@dataclass
class Case:
    args: list[str]
    says: list[str]  # parts of the error line
    files: dict[str, bytes] = field(default_factory=dict)  # tmp files the args refer to as {NAME}


SETTING_CASES: dict[str, Case] = {
    "seed-text": Case(["seed=abc"], ["seed: expected an integer", "found 'abc'"]),
    "seed-negative": Case(["seed=-1"], ["seed: expected an integer in [0, ", "found -1"]),
    "keep-ratio-above-1": Case(["prune.keep_ratio=1.5"], ["prune.keep_ratio: expected a number in (0, 1]", "1.5"]),
    "keep-ratio-negative": Case(["prune.keep_ratio=-0.1"], ["prune.keep_ratio", "found -0.1"]),
    "keep-ratio-zero": Case(["prune.keep_ratio=0"], ["prune.keep_ratio", "found 0"]),
    "keep-ratio-text": Case(["prune.keep_ratio=abc"], ["prune.keep_ratio", "found 'abc'"]),
    "prune-target-unknown": Case(["prune.target=count"], ["prune.target: expected one of ratio, absolute", "'count'"]),
    "prune-absolute-no-count": Case(
        ["prune.target=absolute"], ["prune.n_target / prune.n_target_per_mpx: expected exactly one of them"]
    ),
    "prune-every-unknown": Case(["prune.every=second"], ["prune.every: expected one of keyframe, frame", "'second'"]),
    "threads-text": Case(["threads=abc"], ["threads: expected an integer >= 1 or null", "found 'abc'"]),
    "threads-negative": Case(["threads=-1"], ["threads", "found -1"]),
    "threads-zero": Case(["threads=0"], ["threads", "found 0"]),
    "max-frames-text": Case(["max_frames=abc"], ["max_frames: expected an integer >= 2", "found 'abc'"]),
    "max-frames-one": Case(["max_frames=1"], ["max_frames", "found 1"]),
    "warmup-text": Case(["warmup_frames=abc"], ["warmup_frames: expected an integer >= 0", "found 'abc'"]),
    "device-unknown": Case(["device=gpu"], ["device: expected auto, cpu or cuda[:N]", "found 'gpu'"]),
    "progress-not-bool": Case(["progress=maybe"], ["progress: expected true or false", "found 'maybe'"]),
    "eval-every-zero": Case(["eval.every=0"], ["eval.every: expected an integer >= 1", "found 0"]),
    "eval-align-unknown": Case(["eval.ate_align=foo"], ["eval.ate_align: expected one of se3, sim3, none", "'foo'"]),
    "eval-max-diff-zero": Case(["eval.max_diff_s=0"], ["eval.max_diff_s: expected a number > 0", "found 0"]),
    "eval-unknown-key": Case(["+eval.evry=2"], ["eval has no setting 'evry'", "every"]),
    "lpips-weights-missing": Case(
        ["eval.lpips_weights={TMP}/nope.pth"], ["eval.lpips_weights: expected an existing file"]
    ),
    "lpips-weights-corrupt": Case(
        ["eval.lpips_weights={TMP}/bad.pth"], ["eval.lpips_weights: cannot load"], {"bad.pth": b"not a checkpoint"}
    ),
    "memory-not-bool": Case(["memory.torch_live=maybe"], ["memory.torch_live: expected true or false", "'maybe'"]),
    "unknown-top-key": Case(["+nonsense=1"], ["unknown setting 'nonsense'", "expected one of"]),
    "unknown-key-no-plus": Case(["eval.nonsense=1"], ["eval: expected a setting among every", "found nonsense"]),
    "unknown-dataset": Case(
        ["dataset=nope"], ["unknown dataset 'nope'", "available: euroc, kitti, sevenscenes, synthetic, tum"]
    ),
    "unknown-strategy": Case(["+strategy=pockt"], ["unknown strategy 'pockt'; did you mean 'pocket'?"]),
    "strategy-param-no-plus": Case(
        ["+strategy=pocket", "strategy.params.nonsense=1"],
        ["strategy.params: expected a setting among", "budget_min", "found nonsense"],
    ),
    "strategy-param-plus": Case(
        ["+strategy=pocket", "+strategy.params.nonsense=1"],
        ["strategy 'pocket': expected parameters among", "budget_min", "found 'nonsense'"],
    ),
    "strategy-param-type": Case(
        ["+strategy=pocket", "strategy.params.budget_min=abc"],
        ["strategy 'pocket' parameter budget_min: expected an integer", "found 'abc'"],
    ),
    "strategy-param-range": Case(
        ["+strategy=mask", "strategy.params.gumbel_tau=0"],
        ["strategy 'mask': gumbel_tau: expected a number > 0", "found 0"],
    ),
    "strategy-param-choice": Case(
        ["+strategy=area", "strategy.params.area=square"],
        ["strategy 'area': area: expected one of exact, analytic, radius", "'square'"],
    ),
    "slam-type": Case(["slam.tracking_iters=abc"], ["slam.tracking_iters: expected an integer", "found 'abc'"]),
    "slam-range": Case(["slam.kf_every=0"], ["slam.kf_every: expected an integer >= 1", "found 0"]),
    "slam-choice": Case(["slam.tracking_init=magic"], ["slam.tracking_init: expected one of velocity, flow_pnp"]),
    "slam-frontend-type": Case(
        ["+slam.flow_pnp.min_inliers=abc"], ["slam.flow_pnp.min_inliers: expected an integer", "found 'abc'"]
    ),
    "dataset-size": Case(["dataset.width=8"], ["dataset.width: expected an integer >= 16", "found 8"]),
    "dataset-range": Case(["dataset=kitti", "dataset.downscale=0"], ["dataset.downscale: expected an integer >= 1"]),
    "dataset-choice": Case(["dataset=kitti", "dataset.color=sepia"], ["dataset.color: expected one of auto, color"]),
    "frame-range": Case(
        ["dataset=kitti", "dataset.first=5", "dataset.last=2"], ["expected first <= last", "first=5 last=2"]
    ),
    "run-dir-is-file": Case(
        ["hydra.run.dir={TMP}/afile"], ["hydra.run.dir: expected a directory, found the file"], {"afile": b""}
    ),
    "run-dir-under-file": Case(
        ["hydra.run.dir={TMP}/afile/run"], ["hydra.run.dir: expected a directory"], {"afile": b""}
    ),
    "run-dir-unwritable": Case(
        ["hydra.run.dir=/proc/pocketbench/run"], ["hydra.run.dir: expected a writable directory", "/proc"]
    ),
    "out-dir-is-file": Case(["out_dir={TMP}/afile"], ["out_dir: expected a directory, found the file"], {"afile": b""}),
    "out-dir-unwritable": Case(["out_dir=/proc/pocketbench"], ["out_dir: expected a writable directory"]),
    "sweep-dir-unwritable": Case(
        ["--multirun", "seed=0,1", "hydra.sweep.dir=/proc/pocketbench"],
        ["hydra.sweep.dir: expected a writable directory"],
    ),
    "sweep-bad-fixed-key": Case(
        ["--multirun", "seed=0,1", "+strategy=pocket", "strategy.params.nonsense=1"],
        ["strategy.params: expected a setting among", "found nonsense"],
    ),
}


@pytest.mark.parametrize("name", sorted(SETTING_CASES))
def test_bad_setting_is_refused_before_any_work(name: str, tmp_path: Path) -> None:
    case = SETTING_CASES[name]
    for fname, data in case.files.items():
        (tmp_path / fname).write_bytes(data)
    run_dir = tmp_path / "run"
    args = [a.replace("{TMP}", str(tmp_path)) for a in case.args]
    if not any(a.startswith(("hydra.run.dir=", "hydra.sweep.dir=")) for a in args):
        args.append(f"hydra.run.dir={run_dir}" if "--multirun" not in args else f"hydra.sweep.dir={run_dir}")
    res = run_cli([*tiny(args), *args])
    assert res.code == 2, (res.code, res.stderr)
    assert res.stderr.strip() == res.error_line, res.stderr  # the one line and nothing else
    for part in case.says:
        assert part in res.error_line, res.error_line
    assert res.error_line == res.error_line.rstrip() and "\n" not in res.error_line
    assert not run_dir.exists()  # refused before Hydra made a run dir
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(case.files)


# --------------------------------------------------------------------------- sweeps
def test_sweep_records_a_bad_value_as_failed_and_goes_on(tmp_path: Path) -> None:
    """Each job is validated where it runs: the bad ones are recorded, none stops the sweep."""
    res = run_cli(["--multirun", "+experiment=tiny", "seed=abc,-3", f"hydra.sweep.dir={tmp_path}"])
    assert res.code == 0, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 2 and "Traceback" not in res.stderr, res.stderr
    records = {p.parent.name: json.loads(p.read_text()) for p in tmp_path.glob("*/metrics.json")}
    assert sorted(records) == ["+experiment=tiny,seed=-3", "+experiment=tiny,seed=abc"]
    for name, rec in records.items():
        assert rec["status"] == "failed" and rec["error"].startswith("seed: expected an integer"), rec
        assert f"error: {rec['error']}" in errors
        assert rec["metrics"] == {} and rec["run"]["strategy"] == "none" and rec["run"]["dataset"] == "synthetic"
        assert {p.name for p in (tmp_path / name).iterdir() if not p.name.startswith(".")} <= {
            "cli.log",
            "metrics.json",
        }


def test_sweep_records_a_job_that_cannot_be_composed(tmp_path: Path) -> None:
    res = run_cli(["--multirun", "dataset=nope,nope2", f"hydra.sweep.dir={tmp_path}"])
    assert res.code == 0, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert errors == [
        "error: unknown dataset 'nope'; available: euroc, kitti, sevenscenes, synthetic, tum",
        "error: unknown dataset 'nope2'; available: euroc, kitti, sevenscenes, synthetic, tum",
    ]
    for name in ("nope", "nope2"):
        rec = json.loads((tmp_path / f"dataset={name}" / "metrics.json").read_text())
        assert rec["status"] == "failed" and rec["error"] == errors[0 if name == "nope" else 1][7:]
        assert rec["run"]["dataset"] == name


# --------------------------------------------------------------------------- bad data files
def _tum_copy(tmp_path: Path) -> Path:
    import cv2
    import numpy as np

    seq = tmp_path / "tum" / "rgbd_dataset_freiburg1_test"
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb, depth, gt = [], [], []
    for k in range(4):
        t = 10.0 + 0.1 * k
        cv2.imwrite(str(seq / "rgb" / f"{k}.png"), np.full((48, 64, 3), 40 * k, np.uint8))
        cv2.imwrite(str(seq / "depth" / f"{k}.png"), np.full((48, 64), 5000, np.uint16))
        rgb.append(f"{t:.4f} rgb/{k}.png")
        depth.append(f"{t:.4f} depth/{k}.png")
        gt.append(f"{t:.4f} {0.1 * k:.4f} 0 0 0 0 0 1")
    for name, lines in (("rgb.txt", rgb), ("depth.txt", depth), ("groundtruth.txt", gt)):
        (seq / name).write_text("# header\n" + "\n".join(lines) + "\n")
    return tmp_path / "tum"


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, (path, old)
    path.write_text(text.replace(old, new, 1))


def _lines(path: Path, edit) -> None:
    lines = path.read_text().splitlines()
    edit(lines)
    path.write_text("\n".join(lines) + "\n")


def _kitti_calib(root: Path) -> Path:
    return root / "sequences" / "06" / "calib.txt"


def _nan_in_line_5(lines: list[str]) -> None:
    lines[4] = lines[4].replace(lines[4].split()[3], "nan", 1)


def _swap_rows_2_3(lines: list[str]) -> None:
    lines[1], lines[2] = lines[2], lines[1]


def _set_row(path: Path, key: str, values: str) -> None:
    _lines(path, lambda ls: ls.__setitem__(next(i for i, ln in enumerate(ls) if ln.startswith(key)), f"{key} {values}"))


DATA_CASES = {
    # name: (dataset, breakage(root), parts of the error line)
    "kitti-missing-root": ("kitti", lambda r: shutil.rmtree(r), ["kitti root not found"]),
    "kitti-wrong-seq": (
        "kitti",
        lambda r: (r / "sequences" / "06").rename(r / "sequences" / "07"),
        ["kitti sequence '06' not found", "has: 07"],
    ),
    "kitti-short-poses": (
        "kitti",
        lambda r: _lines(r / "poses" / "06.txt", lambda ls: ls.pop()),
        ["expected 51 poses", "found 50"],
    ),
    "kitti-nan-pose": (
        "kitti",
        lambda r: _lines(r / "poses" / "06.txt", _nan_in_line_5),
        ["line 5", "expected finite numbers", "nan"],
    ),
    "kitti-missing-calib-key": (
        "kitti",
        lambda r: _lines(_kitti_calib(r), lambda ls: ls.pop(1)),
        ["expected P1", "found keys"],
    ),
    "kitti-calib-text": ("kitti", lambda r: _edit(_kitti_calib(r), "P1:", "P1: x"), ["expected numbers after 'P1:'"]),
    "kitti-singular-P": (
        "kitti",
        lambda r: _set_row(_kitti_calib(r), "P0:", "707.0912 0 601.8873 0 0 707.0912 183.1104 0 0 0 0 0"),
        ["expected an invertible left 3x3 block in P0", "singular"],
    ),
    "kitti-negative-fx": (
        "kitti",
        lambda r: _set_row(_kitti_calib(r), "P0:", "-707.0912 0 601.8873 0 0 707.0912 183.1104 0 0 0 1 0"),
        ["expected positive focal lengths in P0", "fx=-707.091"],
    ),
    "kitti-times-count": (
        "kitti",
        lambda r: _lines(r / "sequences" / "06" / "times.txt", lambda ls: ls.pop()),
        ["expected 51 lines", "found 50"],
    ),
    "kitti-stereo-mismatch": (
        "kitti",
        lambda r: (r / "sequences" / "06" / "image_1" / "000050.png").unlink(),
        ["expected matching images in image_0 and image_1", "found 51 and 50"],
    ),
    "kitti-corrupt-first-png": (
        "kitti",
        lambda r: _corrupt(r / "sequences" / "06" / "image_0" / "000000.png"),
        ["image unreadable", "000000.png"],
    ),
    "euroc-fx-zero": (
        "euroc",
        lambda r: _edit(_sensor(r), "intrinsics: [458.654,", "intrinsics: [0.0,"),
        ["key 'intrinsics': expected positive focal lengths", "found 0, 457.296"],
    ),
    "euroc-fx-negative": (
        "euroc",
        lambda r: _edit(_sensor(r), "intrinsics: [458.654,", "intrinsics: [-458.654,"),
        ["key 'intrinsics': expected positive focal lengths", "-458.654"],
    ),
    "euroc-resolution-zero": (
        "euroc",
        lambda r: _edit(_sensor(r), "resolution: [752, 480]", "resolution: [0, 0]"),
        ["key 'resolution': expected positive integer width and height", "[0.0, 0.0]"],
    ),
    "euroc-bad-yaml": ("euroc", lambda r: _edit(_sensor(r), "rows: 4", "rows: [4"), ["expected valid yaml"]),
    "euroc-short-intrinsics": (
        "euroc",
        lambda r: _edit(_sensor(r), "367.215, 248.375]", "367.215]"),
        ["expected 4 finite numbers, found 3"],
    ),
    "euroc-alias-missing": (
        "euroc",
        lambda r: (r / "V1_01_micro").rename(r / "elsewhere"),
        ["euroc sequence 'V1_01_micro' not found"],
    ),
    "tum-duplicate-stamp": (
        "tum",
        lambda r: _lines(_gt(r), lambda ls: ls.insert(3, ls[2])),
        ["groundtruth.txt line 4: expected strictly increasing timestamps", "duplicate of line 3"],
    ),
    "tum-unsorted-stamps": (
        "tum",
        lambda r: _lines(_gt(r), lambda ls: ls.__setitem__(slice(2, 4), ls[3:1:-1])),
        ["groundtruth.txt line 4: expected strictly increasing", "after"],
    ),
    "tum-unsorted-rgb": (
        "tum",
        lambda r: _lines(_tum(r) / "rgb.txt", _swap_rows_2_3),
        ["rgb list", "line 3: expected strictly increasing"],
    ),
}


def _corrupt(path: Path) -> None:
    path.unlink()
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)


def _sensor(root: Path) -> Path:
    return root / "V1_01_micro" / "mav0" / "cam0" / "sensor.yaml"


def _tum(root: Path) -> Path:
    return root / "rgbd_dataset_freiburg1_test"


def _gt(root: Path) -> Path:
    return _tum(root) / "groundtruth.txt"


@pytest.mark.parametrize("name", sorted(DATA_CASES))
def test_bad_data_file_fails_before_any_work(name: str, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    dataset, breakage, parts = DATA_CASES[name]
    if dataset == "tum":
        root, seq = _tum_copy(tmp_path), "fr1_test"
    else:
        fixture = "make_kitti_copy" if dataset == "kitti" else "euroc_copy"
        root = request.getfixturevalue(fixture)() if dataset == "kitti" else request.getfixturevalue(fixture)
        seq = "06" if dataset == "kitti" else "V1_01_micro"
    breakage(root)
    run_dir = tmp_path / "run"
    no_cache = [] if dataset == "tum" else ["dataset.cache_dir=null"]
    res = run_cli([f"dataset={dataset}", f"seq={seq}", f"dataset.root={root}", *no_cache, f"hydra.run.dir={run_dir}"])
    assert res.code == 2, res.stderr
    line = res.error_line
    for part in parts:
        assert part in line, line
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "failed" and f"error: {record['error']}" == line
    assert not (run_dir / "keyframes.csv").exists()  # refused before the SLAM loop


@pytest.mark.parametrize(
    ("dataset", "given", "canonical"),
    [
        ("kitti", "6", "06"),
        ("kitti", "06", "06"),
        ("euroc", "V101", "V1_01_easy"),
        ("euroc", "v1_01", "V1_01_easy"),
        ("euroc", "V1_01_easy", "V1_01_easy"),
        ("tum", "fr1_desk", "rgbd_dataset_freiburg1_desk"),
        ("synthetic", "007", "7"),
        ("sevenscenes", "1", "seq-01"),
        ("sevenscenes", "seq-01", "seq-01"),
    ],
)
def test_one_sequence_one_name(dataset: str, given: str, canonical: str) -> None:
    from bench.datasets import canonical_seq
    from bench.run.identity import run_keys

    assert canonical_seq(dataset, given) == canonical
    assert run_keys(cli.compose([f"dataset={dataset}", f"seq={given}"]))["seq"] == canonical


def test_report_counts_one_sequence_once(tmp_path: Path) -> None:
    """Records written before canonical names (seq '6' and '06') land in one report column."""
    from bench.report.collect import collect

    for name, seq in (("a", "6"), ("b", "06")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.json").write_text(
            json.dumps(
                {
                    "status": "ok",
                    "error": None,
                    "metrics": {"ate_rmse_m": 0.1},
                    "run": {"strategy": "none", "dataset": "kitti", "seq": seq, "seed": 0, "keep_ratio": None},
                }
            )
        )
    assert sorted(set(collect([tmp_path]).runs["seq"])) == ["06"]


# --------------------------------------------------------------------------- resume key
def test_resume_redoes_on_any_change_and_says_why() -> None:
    from bench.run.resume import redo_reason, resume_key

    code = {"git_commit": "a" * 40, "git_dirty": False, "diff_sha": None, "package": "0.1.0"}
    key = resume_key("cfg1", code, {"calib.txt": "x", "images (2 files)": "y"})
    done = {"status": "ok", "run": dict(key)}
    assert redo_reason(done, key) is None
    assert redo_reason({**done, "status": "lost"}, key) is None
    assert redo_reason(None, key) == "no previous results"
    assert redo_reason({**done, "status": "interrupted"}, key) == "the previous run ended interrupted"
    assert redo_reason({**done, "status": "failed"}, key) == "the previous run ended failed"
    assert redo_reason(done, {**key, "config_hash": "cfg2"}) == "config changed (hash cfg1 -> cfg2)"
    dirty = {**code, "git_dirty": True, "diff_sha": "d" * 12}
    expected = f"code version changed ({'a' * 12} -> {'a' * 12}+dirty dddddddd)"
    assert redo_reason(done, {**key, "code_version": dirty}) == expected
    changed = {**key, "inputs": {"calib.txt": "z", "images (2 files)": "y"}}
    assert redo_reason(done, changed) == "input files changed: calib.txt"
    old = {**done, "run": {k: v for k, v in key.items() if k != "inputs"}}
    assert redo_reason(old, key) == "input files not fingerprinted by the previous run"


def test_resume_keeps_runs_across_commits_that_change_no_code() -> None:
    """A docs-only commit keeps a finished sweep; a code change, or an older record without the
    tree hash, redoes it."""
    from bench.run.resume import redo_reason, resume_key

    code = {"git_commit": "a" * 40, "code_tree": "t1", "git_dirty": False, "diff_sha": None, "package": "0.1.0"}
    done = {"status": "ok", "run": resume_key("cfg1", code, {})}
    assert redo_reason(done, resume_key("cfg1", {**code, "git_commit": "b" * 40}, {})) is None
    assert "code version changed" in redo_reason(done, resume_key("cfg1", {**code, "code_tree": "t2"}, {}))
    legacy = {**done, "run": resume_key("cfg1", {k: v for k, v in code.items() if k != "code_tree"}, {})}
    assert "code version changed" in redo_reason(legacy, resume_key("cfg1", {**code, "git_commit": "b" * 40}, {}))


def test_input_fingerprint_follows_content_and_images(tmp_path: Path) -> None:
    from bench.run.resume import input_fingerprint

    calib, img = tmp_path / "calib.txt", tmp_path / "000000.png"
    calib.write_text("P0: 1 2 3")
    img.write_bytes(b"png")
    first = input_fingerprint([calib, img])
    assert set(first) == {str(calib), "images (1 files)"}
    calib.write_text("P0: 1 2 4")  # same size, new content
    assert input_fingerprint([calib, img])[str(calib)] != first[str(calib)]
    img.write_bytes(b"png2")
    second = input_fingerprint([calib, img])["images (1 files)"]
    assert second != first["images (1 files)"]
    img.write_bytes(b"pnh2")  # same size: the content decides, not the size
    assert input_fingerprint([calib, img])["images (1 files)"] != second
    stamp = input_fingerprint([calib, img])["images (1 files)"]
    os.utime(img, (10**9, 10**9))  # a copy or remount changes the mtime alone: the same input, no redo
    assert input_fingerprint([calib, img])["images (1 files)"] == stamp
