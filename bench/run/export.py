"""The map as a file a 3DGS viewer opens: ``map.ply`` at the end of every run, and per-keyframe
snapshots turned into PLY on demand (``python -m bench.export RUN_DIR --keyframe K``).

Layout: the one the reference 3DGS code writes and viewers read (binary little-endian, one
``vertex`` element, float32): ``x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2 rot_0..3``.
- ``f_dc``: the harness stores plain RGB in [0, 1] per Gaussian (no spherical harmonics, no sigmoid;
  ``bench/slam/raster.py`` blends ``colors`` as they are), and viewers decode ``rgb = 0.5 + C0 * f_dc``,
  so ``f_dc = (rgb - 0.5) / C0``.
- ``f_rest``: 45 zeros, the degree-3 layout most viewers expect (the map has no higher bands).
- ``nx ny nz``: zeros, as the reference code writes them.
- ``opacity``, ``scale_*``, ``rot_*``: the map's own ``opacity_logits``, ``log_scales`` and ``quats`` (wxyz,
  unnormalised, as viewers accept), copied bit for bit.
A strategy's render mask (MaskGaussian hides Gaussians without deleting them) is not applied: the
file holds the map's parameters, so a masked Gaussian shows in a viewer.

Snapshots (``save_maps=every_keyframe``) are ``maps/kf_NNN.npz`` with the five parameter arrays,
uncompressed float32: 56 bytes per Gaussian, written after each keyframe's prune.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from bench.errors import ArgumentParser, BenchError, ConfigError, failed

C0 = 0.28209479177387814  # the degree-0 spherical-harmonic constant, 1 / (2 sqrt(pi))
N_REST = 45  # f_rest_* properties: 3 colours x 15 coefficients of bands 1-3
MAP_FILE = "map.ply"
SNAPSHOT_DIR = "maps"
SAVE_MAPS = ("final", "every_keyframe")
PARAMS = ("means", "log_scales", "quats", "opacity_logits", "colors")  # the arrays a snapshot holds
PROPERTIES: tuple[str, ...] = (
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", *(f"f_rest_{i}" for i in range(N_REST)),
    "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
)  # fmt: skip


def map_arrays(gaussians) -> dict[str, np.ndarray]:
    """The map's parameters as float32 numpy arrays (``means`` [N, 3], ``log_scales`` [N, 3],
    ``quats`` [N, 4], ``opacity_logits`` [N], ``colors`` [N, 3]), detached copies."""
    return {k: gaussians.params[k].detach().cpu().float().numpy().copy() for k in PARAMS}


def rgb_to_dc(colors: np.ndarray) -> np.ndarray:
    """[N, 3] RGB in [0, 1] -> [N, 3] SH DC coefficients (viewers add 0.5 after multiplying by C0)."""
    return ((colors.astype(np.float32) - np.float32(0.5)) / np.float32(C0)).astype(np.float32)


def ply_vertices(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """The structured [N] array of the PLY's vertex element, in ``PROPERTIES`` order."""
    n = arrays["means"].shape[0]
    vertices = np.zeros(n, dtype=[(name, "<f4") for name in PROPERTIES])
    columns = {
        "x": arrays["means"][:, 0], "y": arrays["means"][:, 1], "z": arrays["means"][:, 2],
        "opacity": arrays["opacity_logits"],
        **{f"f_dc_{i}": rgb_to_dc(arrays["colors"])[:, i] for i in range(3)},
        **{f"scale_{i}": arrays["log_scales"][:, i] for i in range(3)},
        **{f"rot_{i}": arrays["quats"][:, i] for i in range(4)},
    }  # fmt: skip
    for name, values in columns.items():
        vertices[name] = values
    return vertices


def write_ply(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write ``arrays`` (``map_arrays``) as a binary 3DGS PLY at ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")  # atomic: a reader never sees half a map
    try:
        PlyData([PlyElement.describe(ply_vertices(arrays), "vertex")], text=False, byte_order="<").write(str(tmp))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_map(path: Path, gaussians) -> Path:
    """``map.ply`` of a live ``GaussianMap``."""
    return write_ply(path, map_arrays(gaussians))


def save_snapshot(run_dir: Path, keyframe: int, gaussians) -> Path:
    """``maps/kf_NNN.npz``: the map after keyframe ``keyframe``'s prune, for ``python -m bench.export``."""
    path = Path(run_dir) / SNAPSHOT_DIR / f"kf_{keyframe:03d}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    # mypy matches **arrays against savez's allow_pickle: bool as well (numpy >= 2.1 stubs); the keys are PARAMS
    np.savez(path, **map_arrays(gaussians))  # type: ignore[arg-type]
    return path


def snapshot_keyframes(run_dir: Path) -> list[int]:
    """The keyframes that have a snapshot in ``run_dir``."""
    found = []
    for p in (Path(run_dir) / SNAPSHOT_DIR).glob("kf_*.npz"):
        try:
            found.append(int(p.stem[3:]))
        except ValueError:
            continue
    return sorted(found)


def read_snapshot(path: Path) -> dict[str, np.ndarray]:
    """A ``maps/kf_NNN.npz`` snapshot's ``PARAMS`` arrays (float32); a ``ConfigError`` line for a truncated or
    corrupt file, or for arrays that do not describe one set of Gaussians."""
    try:
        with np.load(path) as data:
            arrays = {k: np.asarray(data[k], dtype=np.float32) for k in PARAMS}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # truncated, corrupt
        found = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"expected '{path}' to hold the arrays {', '.join(PARAMS)}, found: {found}") from None
    check_shapes(arrays, path)
    return arrays


def export_keyframe(run_dir: Path, keyframe: int, out: Path | None = None) -> Path:
    """Turn the snapshot of ``keyframe`` into a PLY (default ``RUN_DIR/map_kfNNN.ply``)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"expected a run dir, found no directory at '{run_dir}'")
    path = run_dir / SNAPSHOT_DIR / f"kf_{keyframe:03d}.npz"
    if not path.is_file():
        have = snapshot_keyframes(run_dir)
        found = f"snapshots of keyframes {', '.join(map(str, have))}" if have else "no snapshots"
        raise ConfigError(
            f"expected a snapshot of keyframe {keyframe} in '{run_dir / SNAPSHOT_DIR}' "
            f"(made by runs with save_maps=every_keyframe), found {found}"
        )
    target = Path(out) if out is not None else run_dir / f"map_kf{keyframe:03d}.ply"
    if target.is_dir():
        raise ConfigError(f"--out: expected a PLY file path, found the directory '{target}'")
    arrays = read_snapshot(path)
    try:
        return write_ply(target, arrays)
    except OSError as exc:
        raise ConfigError(f"--out: expected a writable file path, found '{target}': {exc.strerror or exc}") from None


WIDTHS = {"means": 3, "log_scales": 3, "quats": 4, "opacity_logits": None, "colors": 3}  # per Gaussian; None: [N]


def check_shapes(arrays: dict[str, np.ndarray], path: Path) -> None:
    """One ``ConfigError`` line unless ``arrays`` (``PARAMS``) describe one set of N Gaussians: ``means`` [N, 3],
    ``log_scales`` [N, 3], ``quats`` [N, 4], ``opacity_logits`` [N], ``colors`` [N, 3]."""
    n = len(arrays["means"]) if arrays["means"].ndim else -1
    bad = [name for name, width in WIDTHS.items() if arrays[name].shape != ((n,) if width is None else (n, width))]
    if bad:
        expected = ", ".join(f"{k} [N{'' if w is None else f', {w}'}]" for k, w in WIDTHS.items())
        found = ", ".join(f"{k} {list(arrays[k].shape)}" for k in WIDTHS)
        raise ConfigError(f"expected '{path}' to hold one map ({expected}), found {found}")


def read_ply(path: Path) -> dict[str, np.ndarray]:
    """A 3DGS PLY back as ``map_arrays`` keys (``colors`` decoded from f_dc) plus ``f_dc`` [N, 3]."""
    v = PlyData.read(str(path))["vertex"].data
    f_dc = np.stack([v[f"f_dc_{i}"] for i in range(3)], 1)
    return {
        "means": np.stack([v["x"], v["y"], v["z"]], 1),
        "log_scales": np.stack([v[f"scale_{i}"] for i in range(3)], 1),
        "quats": np.stack([v[f"rot_{i}"] for i in range(4)], 1),
        "opacity_logits": np.asarray(v["opacity"]),
        "colors": (np.float32(0.5) + np.float32(C0) * f_dc).astype(np.float32),
        "f_dc": f_dc,
    }


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(
        prog="python -m bench.export",
        description="Write a keyframe's map snapshot (save_maps=every_keyframe) as a "
        "3DGS PLY; every run already leaves its final map as map.ply.",
    )
    parser.add_argument("run_dir", type=Path, help="a run dir")
    parser.add_argument("--keyframe", type=int, required=True, help="keyframe index K (maps/kf_KKK.npz)")
    parser.add_argument("--out", type=Path, default=None, help="PLY path (default RUN_DIR/map_kfKKK.ply)")
    args = parser.parse_args(argv)
    try:
        path = export_keyframe(args.run_dir, args.keyframe, args.out)
    except BenchError as exc:
        return failed(exc)
    print(f"wrote {path}")
    return 0
