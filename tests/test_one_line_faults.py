"""Faults that were tracebacks, now one line (issue 62, F and G): a full disk or a read-only dir mid-run, an
export of a snapshot whose arrays disagree, a binary --labels file, a plugin that fails to import."""

from __future__ import annotations

import errno
import json
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np

from tests.test_bad_input import run_cli
from tests.test_faults import call, one_line

TINY = ["+experiment=tiny", "threads=1", "eval.lpips=false", "max_frames=3"]


def test_a_full_disk_at_the_final_map_write_ends_the_run_failed_in_one_line(tmp_path: Path, monkeypatch) -> None:
    import bench.run.export as export

    def full(self, stream):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(export.PlyData, "write", full)
    run_dir = tmp_path / "run"
    got = run_cli([*TINY, f"hydra.run.dir={run_dir}"])
    assert got.code == 2
    says = f"error: run dir {run_dir}: expected to write its files, found: No space left on device"
    assert got.error_line == says
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "failed" and record["error"] == says.removeprefix("error: ")
    assert record["metrics"]["num_frames"] == 3  # what the run computed is kept
    assert not list(run_dir.glob("*.tmp")) and not (run_dir / "map.ply").exists()


def test_a_run_dir_made_read_only_mid_run_is_one_line(tmp_path: Path, monkeypatch) -> None:
    """Root ignores permission bits, so the refusal is raised where the kernel would raise it: the next row."""
    from bench.run.rows import FlushedRows

    run_dir = tmp_path / "run"

    def read_only(self, row):
        raise PermissionError(errno.EACCES, "Permission denied", str(self.path))

    monkeypatch.setattr(FlushedRows, "writerow", read_only)
    got = run_cli([*TINY, f"hydra.run.dir={run_dir}"])
    assert got.code == 2
    assert got.error_line.startswith(f"error: run dir {run_dir}: expected to write {run_dir / 'keyframes.csv'}")
    assert got.error_line.endswith("found: Permission denied")


def test_export_of_a_snapshot_whose_arrays_disagree_is_one_line(tmp_path: Path, capsys) -> None:
    from bench.run.export import main

    (tmp_path / "maps").mkdir()
    n = 5
    np.savez(
        tmp_path / "maps" / "kf_000.npz",
        means=np.zeros((n, 3)), log_scales=np.zeros((n, 3)), quats=np.zeros((n - 1, 4)),
        opacity_logits=np.zeros(n), colors=np.zeros((n, 3)),
    )  # fmt: skip
    line = one_line(call(main, [str(tmp_path), "--keyframe", "0"], capsys))
    assert "to hold one map (means [N, 3], log_scales [N, 3], quats [N, 4], opacity_logits [N], colors [N, 3])" in line
    assert line.endswith("found means [5, 3], log_scales [5, 3], quats [4, 4], opacity_logits [5], colors [5, 3]")
    assert not list(tmp_path.glob("*.ply"))


def test_a_binary_labels_file_is_one_line(tmp_path: Path, capsys) -> None:
    from bench.report.__main__ import main
    from tests.report.conftest import write_run

    write_run(tmp_path / "runs" / "a", strategy="none", seq="06")
    labels = tmp_path / "labels.yaml"
    labels.write_bytes(bytes(range(256)))
    out = tmp_path / "out"
    line = one_line(call(main, [str(tmp_path / "runs"), "--out", str(out), "--labels", str(labels)], capsys))
    assert line.startswith(f"error: cannot read labels file '{labels}': ")
    assert not out.exists()


def test_a_plugin_that_fails_to_import_says_why(monkeypatch) -> None:
    import bench.config.plugins as plugins

    real = plugins._entry_points

    def with_broken(group: str) -> dict[str, EntryPoint]:
        found = real(group)
        if group == "pocketbench.strategies":
            found["broken"] = EntryPoint("broken", "no_such_module_62:Broken", group)
        return found

    monkeypatch.setattr(plugins, "_entry_points", with_broken)
    got = run_cli(["+experiment=tiny", "+strategy=broken"])
    assert got.code == 2
    assert got.error_line == (
        "error: strategy 'broken' failed to load from no_such_module_62:Broken: No module named 'no_such_module_62'"
    )


def test_a_command_reports_a_known_failure_as_one_line(capsys):
    """``bench.errors.failed``: what every command's ``main`` returns on a ``BenchError``."""
    from bench.errors import ConfigError, failed

    assert failed(ConfigError("x: expected 1, found 2")) == 2
    assert failed(ConfigError("y"), 3) == 3
    assert capsys.readouterr().err == "error: x: expected 1, found 2\nerror: y\n"
