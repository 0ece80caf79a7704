"""Hydra's own files in a run dir (``cli.log`` and ``.hydra/``), written only by a job that does work.

Hydra writes them when a job starts, before our code has decided anything, so a rerun that is
skipped (its finished results match) or refused (a passing reason) used to append to the finished
run's log and rewrite its ``.hydra/``: the dir then described a job that never ran there. Here Hydra
writes nothing (``hydra.output_subdir: null``; the log's file handler holds its lines back), and
``keep`` writes both once the job records something of its own.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, cast

from omegaconf import DictConfig, OmegaConf

HYDRA_SUBDIR = ".hydra"  # where Hydra itself would write the job's configs


class HeldFileHandler(logging.Handler):
    """A file handler that holds records in memory until ``open`` (the job does work), then writes
    them and every later one to ``filename``; never opened, it writes nothing and drops them on close.

    Hydra's job logging builds it from ``bench/conf/hydra/job_logging/bench.yaml``.
    """

    def __init__(self, filename: str, mode: str = "a", encoding: str | None = "utf-8") -> None:
        super().__init__()
        self.filename, self.mode, self.encoding = filename, mode, encoding
        self.held: list[logging.LogRecord] = []
        self.file: logging.FileHandler | None = None

    def open(self, filename: str | None = None) -> None:
        """Start writing, to ``filename`` if given: the held records first, in order."""
        if self.file is not None:
            return
        self.file = logging.FileHandler(filename or self.filename, self.mode, self.encoding)
        self.file.setFormatter(self.formatter)
        self.file.setLevel(self.level)
        for record in self.held:
            self.file.handle(record)
        self.held.clear()

    def emit(self, record: logging.LogRecord) -> None:
        if self.file is not None:
            self.file.handle(record)
        else:
            self.held.append(record)

    def flush(self) -> None:
        if self.file is not None:
            self.file.flush()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
        self.held.clear()
        super().close()


def keep(out: Path, task_cfg: DictConfig | None = None, into: Path | None = None) -> None:
    """The job running now records into ``out``: write its ``.hydra/`` configs as Hydra would have
    (``config.yaml``, ``hydra.yaml``, ``overrides.yaml``) and open its held log, in ``into`` when
    given (a redo's staging dir, whose files replace the run's only once it finishes).

    Does nothing outside a Hydra job, or for a dir that is not the job's own output dir (the sweeper
    records a job that never composed without a job of its own).
    """
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return
    # Hydra annotates cfg as Optional[HydraConf]; set, it is the DictConfig {hydra: ...} (hydra-core 1.3)
    hydra_cfg = cast(DictConfig, HydraConfig.instance().cfg)
    runtime_dir = OmegaConf.select(hydra_cfg, "hydra.runtime.output_dir", default=None)
    if runtime_dir is None or Path(str(runtime_dir)).resolve() != Path(out).resolve():
        return
    where = Path(into or out)
    subdir = where / HYDRA_SUBDIR
    subdir.mkdir(parents=True, exist_ok=True)
    files: dict[str, Any] = {"hydra.yaml": hydra_cfg, "overrides.yaml": hydra_cfg.hydra.overrides.task}
    if task_cfg is not None:
        files["config.yaml"] = task_cfg
    for name, node in files.items():
        (subdir / name).write_text(OmegaConf.to_yaml(node), encoding="utf-8")
    for handler in logging.getLogger().handlers:
        if isinstance(handler, HeldFileHandler):
            handler.open(str(where / Path(handler.filename).name))
