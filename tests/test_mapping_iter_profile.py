"""``profiling/mapping_iter_profile.py`` times the parts of a mapping iteration by wrapping functions by name: a
rename in ``bench/slam`` must fail here rather than leave a part at zero, and the wrappers must come off again."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]


def _module():
    sys.path.insert(0, str(REPO / "profiling"))
    try:
        spec = importlib.util.spec_from_file_location(
            "mapping_iter_profile", REPO / "profiling" / "mapping_iter_profile.py"
        )
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(str(REPO / "profiling"))


def test_timers_bill_each_part_and_come_off() -> None:
    from bench.slam import raster, raster_fused
    from bench.slam.raster_fused import autograd as fa

    mod = _module()
    before = {
        "front": raster._front_fused,
        "bin": raster_fused.bin_pairs,
        "kernel": fa.composite_fwd,
        "backward": torch.Tensor.backward,
        "composite_bwd": vars(fa._Composite)["backward"],
    }
    clock = mod.Clock()
    timers = mod.Timers(clock)
    try:
        g = torch.Generator().manual_seed(0)
        n = 200
        means = torch.cat([torch.rand(n, 2, generator=g) * 2 - 1, torch.rand(n, 1, generator=g) * 3 + 3], 1)
        params = [
            t.requires_grad_(True)
            for t in (
                means,
                torch.full((n, 3), -2.5),
                torch.randn(n, 4, generator=g),
                torch.rand(n, generator=g),
                torch.rand(n, 3, generator=g),
            )
        ]
        K = torch.tensor([[40.0, 0, 24], [0, 40.0, 16], [0, 0, 1]])
        out = raster.rasterize(*params, torch.eye(4), K, 48, 32, backend="fused")
        (out.color.sum() + out.depth.sum()).backward()
    finally:
        timers.restore()
    for part in ("projection", "binning", "render_glue", "fwd_kernel", "bwd_kernel", "proj_bwd", "autograd_glue"):
        assert clock.ms.get(part, 0.0) > 0, f"{part} was not timed: {dict(clock.ms)}"
    assert set(clock.ms) <= set(mod.PARTS), set(clock.ms) - set(mod.PARTS)
    assert raster._front_fused is before["front"] and raster_fused.bin_pairs is before["bin"]
    assert fa.composite_fwd is before["kernel"] and torch.Tensor.backward is before["backward"]
    assert vars(fa._Composite)["backward"] is before["composite_bwd"]
    from bench.slam import losses, mapping

    assert mapping.depth_l1 is losses.depth_l1  # the module function is put back, not left wrapped
