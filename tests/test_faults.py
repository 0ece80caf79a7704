"""Faults end in one ``error:`` line (exit 2) or a ``failed`` record, never a traceback, and no
temporary file is left (issue 40, class F); what can be refused is refused before work (class G).
"""

from __future__ import annotations

import errno
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.test_bad_input import Outcome, _tum_copy, run_cli

REPO = Path(__file__).resolve().parents[1]


def call(main, argv: list[str], capsys: pytest.CaptureFixture[str]) -> Outcome:
    """A ``main(argv)`` of one of the module CLIs: exit code and output, argparse's exits included."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return Outcome(code, err, out)


def one_line(res: Outcome) -> str:
    assert res.code == 2, (res.code, res.stderr)
    assert res.stderr.strip() == res.error_line, res.stderr
    return res.error_line


# --------------------------------------------------------------------------- runs
def test_a_route_that_never_moves_is_refused_with_a_record(tmp_path: Path) -> None:
    route = tmp_path / "still.txt"
    route.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 20)
    run_dir = tmp_path / "run"
    res = run_cli(["+experiment=tiny", f"dataset.route_file={route}", f"hydra.run.dir={run_dir}"])
    line = one_line(res)
    assert "expected a route that moves along the ground, found all 12 poses at one spot" in line
    assert json.loads((run_dir / "metrics.json").read_text())["status"] == "failed"


def test_a_directory_in_place_of_the_checkpoint_is_refused_before_work(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    (run_dir / "checkpoint.pt").mkdir(parents=True)
    line = one_line(run_cli(["+experiment=tiny", f"hydra.run.dir={run_dir}"]))
    assert "checkpoint: expected a file or nothing at" in line and "found a directory" in line
    assert not (run_dir / "keyframes.csv").exists()


@pytest.mark.parametrize(
    "fault",
    [
        OSError(errno.ENOSPC, "No space left on device"),
        RuntimeError(
            "[enforce fail at inline_container.cc] . PytorchStreamWriter failed writing file data/0: file write failed"
        ),
    ],
)
def test_a_failed_checkpoint_write_leaves_the_old_one_and_no_tmp(tmp_path: Path, monkeypatch, fault) -> None:
    import torch

    from bench.run import checkpoint as ckpt

    ckpt.save(tmp_path, {"frame": 1})
    before = (tmp_path / "checkpoint.pt").read_bytes()

    def full_disk(obj, fh):
        fh.write(b"partial")
        raise fault

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(ckpt.CheckpointError) as err:
        ckpt.save(tmp_path, {"frame": 2})
    assert str(err.value).startswith(f"checkpoint: expected to write {tmp_path / 'checkpoint.pt'}, found the write")
    assert "\n" not in str(err.value)
    assert (tmp_path / "checkpoint.pt").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


def test_a_list_that_names_a_missing_image_is_refused_before_any_frame(tmp_path: Path) -> None:
    root = _tum_copy(tmp_path)
    (root / "rgbd_dataset_freiburg1_test" / "rgb" / "2.png").unlink()
    run_dir = tmp_path / "run"
    line = one_line(run_cli(["dataset=tum", "seq=fr1_test", f"dataset.root={root}", f"hydra.run.dir={run_dir}"]))
    assert "expected every file the dataset lists" in line and "rgb/2.png missing" in line
    assert json.loads((run_dir / "metrics.json").read_text())["status"] == "failed"
    assert not (run_dir / "traj_est.txt").exists() and not (run_dir / "keyframes.csv").exists()


# --------------------------------------------------------------------------- export
def _snapshot(run_dir: Path) -> Path:
    from bench.run.export import PARAMS, SNAPSHOT_DIR

    shapes = {"means": 3, "log_scales": 3, "quats": 4, "opacity_logits": 0, "colors": 3}
    arrays = {k: np.ones((50, shapes[k]) if shapes[k] else 50, np.float32) for k in PARAMS}
    path = run_dir / SNAPSHOT_DIR / "kf_000.npz"
    path.parent.mkdir(parents=True)
    np.savez(path, **arrays)
    return path


def test_export_of_a_truncated_snapshot_is_one_line(tmp_path: Path, capsys) -> None:
    from bench.run.export import main

    path = _snapshot(tmp_path)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    line = one_line(call(main, [str(tmp_path), "--keyframe", "0"], capsys))
    assert "to hold the arrays means" in line
    assert not list(tmp_path.glob("*.ply*"))


def test_export_out_naming_a_directory_is_one_line(tmp_path: Path, capsys) -> None:
    from bench.run.export import main

    _snapshot(tmp_path)
    (tmp_path / "out").mkdir()
    line = one_line(call(main, [str(tmp_path), "--keyframe", "0", "--out", str(tmp_path / "out")], capsys))
    assert "--out: expected a PLY file path, found the directory" in line
    assert call(main, [str(tmp_path), "--keyframe", "0"], capsys).code == 0  # the snapshot itself is fine
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize("module", ["bench.export", "bench.report", "bench.datasets.prepare", "bench.study"])
def test_usage_errors_are_one_error_line(module: str, capsys) -> None:
    import importlib

    main = importlib.import_module(module if module != "bench.report" else "bench.report.__main__").main
    line = one_line(call(main, ["--no-such-option"], capsys))
    assert line.startswith("error: ")


# --------------------------------------------------------------------------- studies
STUDY_FILES = {
    "syntax": ("hydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0\n", "study 'syntax': expected a study file"),
    "empty": ("", "study 'empty': expected a study file"),
    "override": (
        '# @package _global_\nhydra:\n  sweeper:\n    study:\n      sweeps:\n        a: ["seed=[0"]\n',
        "study 'override' sweep 'a': expected overrides as on a command line",
    ),
}


@pytest.mark.parametrize("name", sorted(STUDY_FILES))
def test_a_broken_study_file_is_one_line(name: str, tmp_path: Path, monkeypatch, capsys) -> None:
    from bench.sweep.study import main

    (tmp_path / "conf" / "study").mkdir(parents=True)
    text, says = STUDY_FILES[name]
    (tmp_path / "conf" / "study" / f"{name}.yaml").write_text(text)
    monkeypatch.chdir(tmp_path)
    assert says in one_line(call(main, [name], capsys))
    assert says in one_line(run_cli(["--multirun", f"+study={name}"]))
    assert not (tmp_path / "multirun").exists()


# --------------------------------------------------------------------------- reports
@pytest.fixture
def report_copy(tmp_path: Path) -> Path:
    src = REPO / "reports" / "fidelity"
    dst = tmp_path / "report"
    dst.mkdir()
    for name in ("runs.csv", "keyframes.csv"):
        shutil.copy(src / name, dst / name)
    return dst


def _edit_csv(path: Path, edit) -> None:
    table = pd.read_csv(path, dtype=str)
    edit(table)
    table.to_csv(path, index=False)


REDRAW_CASES = {
    "keyframes-no-path": ("keyframes.csv", lambda t: t.pop("path"), "expected a path column"),
    "keyframes-text": (
        "keyframes.csv",
        lambda t: t.__setitem__("n_gaussians", "abc"),
        "expected numbers in column 'n_gaussians'",
    ),
    "runs-text": ("runs.csv", lambda t: t.__setitem__("ate_rmse_m", "abc"), "expected numbers in column 'ate_rmse_m'"),
}


@pytest.mark.parametrize("case", sorted(REDRAW_CASES))
def test_redraw_of_a_malformed_table_is_one_line(case: str, report_copy: Path, capsys) -> None:
    from bench.report.__main__ import main

    name, edit, says = REDRAW_CASES[case]
    _edit_csv(report_copy / name, edit)
    assert says in one_line(call(main, ["--redraw", str(report_copy)], capsys))
    assert sorted(p.name for p in report_copy.iterdir()) == ["keyframes.csv", "runs.csv"]  # no figure drawn


@pytest.mark.parametrize("option", [["--format", "bmp"], ["--dpi", "0"]])
def test_report_refuses_its_options_before_writing_tables(option: list[str], tmp_path: Path, capsys) -> None:
    from bench.report.__main__ import main
    from tests.report.conftest import write_run

    for strategy in ("none", "pocket"):
        write_run(tmp_path / "runs" / strategy, strategy=strategy, seq="06")
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.png").write_bytes(b"an older figure")
    line = one_line(call(main, [str(tmp_path / "runs"), "--out", str(out), *option], capsys))
    assert "expected" in line
    assert sorted(p.name for p in out.iterdir()) == ["old.png"]
