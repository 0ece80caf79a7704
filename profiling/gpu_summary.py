"""One line per run dir: status, ATE, PSNR, FPS, wall time, and the CUDA (or CPU) peaks of the first,
middle and last keyframe windows; for the GPU check of the gsplat backend (docs/architecture.md).

    python profiling/gpu_summary.py RUN_DIR [RUN_DIR ...]
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path


def _fmt(v, spec: str) -> str:
    return "n/a" if v is None or v == "" else format(float(v), spec)


def summarize(run: Path) -> str:
    """The line for one run dir (metrics.json and keyframes.csv; what is missing reads n/a)."""
    doc = json.loads((run / "metrics.json").read_text()) if (run / "metrics.json").is_file() else {}
    m = {"status": doc.get("status"), **(doc.get("metrics") or {})}
    rows = list(csv.DictReader((run / "keyframes.csv").open())) if (run / "keyframes.csv").is_file() else []
    col = "cuda_alloc_peak_mib" if rows and rows[0].get("cuda_alloc_peak_mib") else "torch_live_peak_mib"
    picks = [rows[i] for i in sorted({0, len(rows) // 2, len(rows) - 1})] if rows else []
    peaks = " ".join(
        f"kf{r['kf']}:{_fmt(r.get(col), '.0f')}/{_fmt(r.get('cuda_reserved_peak_mib'), '.0f')}" for r in picks
    )
    return (
        f"{run.name}: status={m.get('status', 'n/a')} ATE={_fmt(m.get('ate_rmse_m'), '.3f')}m "
        f"PSNR={_fmt(m.get('psnr_db'), '.2f')}dB FPS={_fmt(m.get('fps'), '.3f')} "
        f"wall={_fmt(m.get('wall_s'), '.0f')}s "
        f"frames={m.get('num_frames', 'n/a')} kfs={len(rows)} G_final={m.get('gaussians_final', 'n/a')} "
        f"peak_{col}(alloc/reserved MiB, first/mid/last)=[{peaks}] "
        f"max_alloc={_fmt(m.get('cuda_alloc_peak_mib'), '.0f')} "
        f"max_reserved={_fmt(m.get('cuda_reserved_peak_mib'), '.0f')}"
    )


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(summarize(Path(arg)))
