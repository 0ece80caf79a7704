"""Cost of one synthetic frame against drive length: the culled cast and the brute-force reference.

The brute-force cast tests every ray against every box of the scene, so its frames cost more the
longer the drive (the scene is built for the whole drive). The culled cast tests a box only on the
rays of its projected rect that have no nearer hit, and only boxes within the haze, so a frame costs
about the same at any length. For each drive length and route the script renders a few frames both
ways back to back in one process, checks the pixels are identical, and prints seconds per frame and
the (ray, box) pairs slab-tested per frame, a count that does not depend on the machine's load.

    python profiling/synthetic_cost.py                          # 40, 400, 1100 frames, both routes
    python profiling/synthetic_cost.py --frames 40 400 --no-brute-force --routes grid
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.datasets.synthetic import open_sequence  # noqa: E402


def frame_cost(seq, i: int, brute_force: bool) -> tuple[float, int, tuple[np.ndarray, np.ndarray]]:
    """(seconds, slab tests, (rgb, depth)) of rendering frame ``i``."""
    before = seq.slab_tests
    t = time.perf_counter()
    img = seq.render(seq.poses[i], brute_force=brute_force)
    return time.perf_counter() - t, seq.slab_tests - before, img


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[40, 400, 1100], help="drive lengths (n_frames)")
    ap.add_argument("--routes", nargs="+", default=["straight", "grid"], choices=["straight", "grid"])
    ap.add_argument("--samples", type=int, default=3, help="frames timed per drive, spread over it")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=192)
    ap.add_argument("--no-brute-force", action="store_true", help="time the culled cast only")
    args = ap.parse_args()
    print(
        f"{'route':9} {'frames':>6} {'boxes':>6} {'culled s':>9} {'brute s':>9} {'culled pairs':>13} "
        f"{'brute pairs':>13} {'same pixels':>11}"
    )
    for route in args.routes:
        for n in args.frames:
            seq = open_sequence({"route": route, "n_frames": n, "width": args.width, "height": args.height})
            rows = []
            for i in np.linspace(0, n - 1, args.samples).round().astype(int):
                t_c, w_c, img_c = frame_cost(seq, int(i), False)
                if args.no_brute_force:
                    rows.append((t_c, w_c, float("nan"), 0, None))
                    continue
                t_b, w_b, img_b = frame_cost(seq, int(i), True)
                same = np.array_equal(img_c[0], img_b[0]) and np.array_equal(img_c[1], img_b[1])
                rows.append((t_c, w_c, t_b, w_b, same))
            med = [statistics.median(r[k] for r in rows) for k in range(4)]
            same = "-" if args.no_brute_force else str(all(r[4] for r in rows))
            print(
                f"{route:9} {n:6d} {len(seq.boxes):6d} {med[0]:9.3f} {med[2]:9.3f} {med[1]:13.3e} {med[3]:13.3e} "
                f"{same:>11}",
                flush=True,
            )


if __name__ == "__main__":
    main()
