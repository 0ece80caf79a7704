"""The fused (compiled) backend against the torch reference: values, gradients, edge cases, determinism."""

from __future__ import annotations

import pytest
import torch

from bench.errors import ConfigError
from bench.measure.memory import MemoryProbe
from bench.slam.raster import antialias_compensation, rasterize, resolve_backend
from bench.slam.se3 import se3_exp

POSE = torch.tensor([0.05, -0.02, 0.1, 0.02, -0.03, 0.01])
FIELDS = ("color", "depth", "alpha")


def scene(n=40, seed=0, z_min=2.0, opacity=(0.05, 0.95), scale=(0.05, 0.3)):
    g = torch.Generator().manual_seed(seed)
    means = torch.cat([torch.rand(n, 2, generator=g) * 2.4 - 1.2, torch.rand(n, 1, generator=g) * 3 + z_min], 1)
    log_scales = torch.log(torch.rand(n, 3, generator=g) * (scale[1] - scale[0]) + scale[0])
    quats = torch.randn(n, 4, generator=g)
    opac = torch.rand(n, generator=g) * (opacity[1] - opacity[0]) + opacity[0]
    colors = torch.rand(n, 3, generator=g)
    K = torch.tensor([[30.0, 0, 19.5], [0, 30.0, 15.5], [0, 0, 1]])
    return means, log_scales, quats, opac, colors, K


def both(params, K, W, H, w2c=None, **kw):
    w2c = se3_exp(POSE) if w2c is None else w2c
    return [rasterize(*params, w2c, K, W, H, backend=b, **kw) for b in ("torch", "fused")]


def assert_same_images(ref, got):
    for f in FIELDS:
        torch.testing.assert_close(getattr(got, f), getattr(ref, f), atol=2e-5, rtol=1e-4, msg=f)
    for f in ("means2d", "cov2d", "depths"):  # the same float32 maths, in another order
        torch.testing.assert_close(getattr(got, f), getattr(ref, f), atol=1e-5, rtol=1e-5, msg=f)
    for f in ("radius_px", "tile_id"):
        torch.testing.assert_close(getattr(got, f), getattr(ref, f), msg=f)


@pytest.mark.parametrize("W,H", [(40, 32), (33, 17), (16, 16), (7, 5)])
@pytest.mark.parametrize("seed", [0, 1])
def test_values_and_stats_match_torch(W, H, seed):
    *params, _ = scene(seed=seed)
    K = torch.tensor([[0.75 * W, 0, W / 2 - 0.5], [0, 0.75 * W, H / 2 - 0.5], [0, 0, 1]])
    ref, got = both(params, K, W, H, stats=True)
    assert ref.alpha.max() > 0.3  # something is visible
    assert_same_images(ref, got)
    torch.testing.assert_close(got.coverage, ref.coverage, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(got.max_weight, ref.max_weight, atol=1e-5, rtol=1e-4)
    assert (got.hit_count - ref.hit_count).abs().max() <= 1  # a pixel exactly at the 1/255 edge may flip
    assert got.hit_count.sum() > 0


def grads(params, K, W, H, backend, target, w2c_base, **kw):
    leaves = [t.clone().requires_grad_(True) for t in params]
    xi = torch.zeros(6, requires_grad=True)
    out = rasterize(*leaves, se3_exp(xi) @ w2c_base, K, W, H, backend=backend, **kw)
    loss = (out.color - target).abs().mean() + 0.1 * out.depth.mean() + 0.3 * (out.alpha - 0.5).pow(2).mean()
    loss.backward()
    return [t.grad for t in leaves] + [xi.grad]


@pytest.mark.parametrize("antialiased,depth_far_m", [(False, None), (True, None), (True, 3.0)])
@pytest.mark.parametrize("seed,W,H", [(0, 40, 32), (2, 33, 17)])
def test_gradients_match_torch_including_pose(seed, W, H, antialiased, depth_far_m):
    """Also with a far limit inside the scene (some Gaussians paint no depth): the fused path gathers the
    Gaussians in view and scatters their gradients back through the conic, the antialiasing factor and the
    painted depth in its own kernels."""
    *params, K = scene(seed=seed)
    if depth_far_m is not None:
        w2c = se3_exp(POSE)
        z = params[0] @ w2c[2, :3] + w2c[2, 3]  # [N] camera depths
        assert (z < depth_far_m).any() and (z >= depth_far_m).any()
    target = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(9))
    kw = {"antialiased": antialiased, "depth_far_m": depth_far_m}
    ref = grads(params, K, W, H, "torch", target, se3_exp(POSE), **kw)
    got = grads(params, K, W, H, "fused", target, se3_exp(POSE), **kw)
    for name, g, r in zip(["means", "log_scales", "quats", "opacity", "colors", "pose"], got, ref, strict=True):
        assert r.abs().max() > 0, name
        torch.testing.assert_close(g, r, atol=2e-6, rtol=2e-3, msg=name)


def test_antialiased_values_match_torch_and_keep_a_small_gaussians_integral():
    """The 2D filter on both backends alike; it dims a sub-pixel Gaussian (whose low-passed footprint
    would otherwise paint a 0.3 px blob at full opacity) and leaves a wide one almost as it was."""
    W, H = 40, 32
    *params, K = scene(seed=3, scale=(0.002, 0.3))
    ref, got = both(params, K, W, H, antialiased=True)
    assert_same_images(ref, got)
    plain = rasterize(*params, se3_exp(POSE), K, W, H, backend="fused")
    assert (got.alpha <= plain.alpha + 1e-6).all() and got.alpha.sum() < plain.alpha.sum()

    def one(scale_m: float, antialiased: bool) -> float:  # the silhouette's integral of one Gaussian at 3 m
        g = [torch.tensor([[0.0, 0.0, 3.0]]), torch.full((1, 3), scale_m).log(), torch.tensor([[1.0, 0, 0, 0]])]
        out = rasterize(*g, torch.tensor([0.5]), torch.ones(1, 3), torch.eye(4), K, W, H, antialiased=antialiased)
        return float(out.alpha.sum())

    tiny, wide = 0.003, 0.3  # 0.03 px and 3 px of standard deviation at fx = 30
    culled = antialias_compensation(torch.zeros(1, 3))  # a zero covariance: culled by its centre
    assert float(culled) == 0.0
    assert one(tiny, True) < 0.25 * one(tiny, False)
    assert one(wide, True) == pytest.approx(one(wide, False), rel=0.05)


def test_saturated_tiles_stop_compositing():
    # many opaque, large Gaussians stacked in depth: T falls below 1e-4 early in every pixel
    *params, K = scene(n=80, seed=3, opacity=(0.9, 0.99), scale=(0.4, 0.8))
    params[0] = params[0] * torch.tensor([0.3, 0.3, 1.0])
    ref, got = both(params, K, 40, 32, stats=True)
    # T stops just above 1e-4, so saturated pixels end with alpha in (0.999, 0.9999]
    assert (ref.alpha > 0.999).float().mean() > 0.3
    assert_same_images(ref, got)
    target = torch.rand(32, 40, 3, generator=torch.Generator().manual_seed(1))
    for g, r in zip(
        grads(params, K, 40, 32, "fused", target, se3_exp(POSE)),
        grads(params, K, 40, 32, "torch", target, se3_exp(POSE)),
        strict=True,
    ):
        torch.testing.assert_close(g, r, atol=2e-6, rtol=2e-3)


def test_gaussian_straddling_tiles():
    # one wide Gaussian centred on the corner of four tiles
    means = torch.tensor([[0.0, 0.0, 2.0]])
    K = torch.tensor([[30.0, 0, 16.0], [0, 30.0, 16.0], [0, 0, 1]])
    params = [
        means,
        torch.log(torch.tensor([[0.2, 0.15, 0.1]])),
        torch.tensor([[0.9, 0.1, 0.2, 0.3]]),
        torch.tensor([0.8]),
        torch.tensor([[0.2, 0.5, 0.9]]),
    ]
    ref, got = both(params, K, 32, 32, w2c=torch.eye(4), stats=True)
    assert int(ref.radius_px[0]) > 8
    assert (ref.alpha[:16, :16] > 0.01).any() and (ref.alpha[16:, 16:] > 0.01).any()
    assert_same_images(ref, got)
    torch.testing.assert_close(got.coverage, ref.coverage, rtol=1e-4, atol=1e-4)


def test_empty_view_and_gaussians_behind_camera():
    *params, K = scene(n=10, seed=4)
    behind = [params[0] * torch.tensor([1.0, 1.0, -1.0])] + params[1:]
    for p in (behind, [t[:0] for t in params]):
        ref, got = both(p, K, 40, 32, w2c=torch.eye(4), stats=True)
        assert got.alpha.abs().max() == 0 and got.color.abs().max() == 0
        assert_same_images(ref, got)
        assert (got.tile_id == -1).all() and (got.radius_px == 0).all()
        assert (got.cov2d == 0).all() and (ref.cov2d == 0).all()  # culled by the centre: not computed
    # nothing in view: like the torch backend, the images carry no gradient (tracking reads that as lost)
    leaves = [t.clone().requires_grad_(True) for t in behind]
    for backend in ("torch", "fused"):
        out = rasterize(*leaves, torch.eye(4), K, 40, 32, backend=backend)
        assert not out.color.requires_grad and not out.alpha.requires_grad


def test_background_shows_through():
    *params, K = scene(seed=5)
    bg = torch.tensor([0.2, 0.4, 0.6])
    ref = rasterize(*params, se3_exp(POSE), K, 40, 32, background=bg, backend="torch")
    got = rasterize(*params, se3_exp(POSE), K, 40, 32, background=bg, backend="fused")
    torch.testing.assert_close(got.color, ref.color, atol=2e-5, rtol=1e-4)


def test_gradients_are_bit_identical_run_to_run():
    *params, K = scene(n=300, seed=6)
    target = torch.rand(32, 40, 3, generator=torch.Generator().manual_seed(2))
    first = grads(params, K, 40, 32, "fused", target, se3_exp(POSE))
    threads = torch.get_num_threads()
    try:
        for n_threads in (1, 2):
            torch.set_num_threads(n_threads)
            again = grads(params, K, 40, 32, "fused", target, se3_exp(POSE))
            for a, b in zip(first, again, strict=True):
                assert torch.equal(a, b)
    finally:
        torch.set_num_threads(threads)


_THREADS_AFTER_RENDER = """
import torch
torch.set_num_threads(1)
from bench.slam.raster import rasterize
g = torch.Generator().manual_seed(0)
n = 64
means = torch.cat([torch.rand(n, 2, generator=g) - 0.5, torch.full((n, 1), 3.0)], 1)
K = torch.tensor([[40.0, 0, 32], [0, 40.0, 32], [0, 0, 1]])
rasterize(means, torch.full((n, 3), -3.0), torch.randn(n, 4, generator=g), torch.full((n,), 0.8),
          torch.rand(n, 3, generator=g), torch.eye(4), K, 64, 64, backend="fused")
print(torch.get_num_threads())
"""


def test_a_fused_render_leaves_torchs_thread_count_alone():
    """numba's OpenMP pool, started by the first fused render of a process, set the OpenMP thread count
    torch shares to every core: a run at threads=1 then ran its torch operations on all of them."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run(
        [sys.executable, "-c", _THREADS_AFTER_RENDER], cwd=root, capture_output=True, text=True, check=True
    )
    assert proc.stdout.split()[-1] == "1", proc.stdout


def test_gaussians_out_of_view_change_nothing_bit_for_bit():
    """The fused path runs on the Gaussians in view only: a map with as many again behind the camera
    and beside the frustum, interleaved, renders and differentiates exactly as the visible ones alone."""
    *params, K = scene(n=60, seed=7)
    *other, _ = scene(n=60, seed=8)
    other[0] = other[0] * torch.tensor([1.0, 1.0, -1.0])  # behind the camera
    other[0][::2, 0] += 40.0  # every other one beside the frustum instead, in front of the camera
    other[0][::2, 2] *= -1.0
    mixed = [torch.stack([a, b], 1).reshape(-1, *a.shape[1:]) for a, b in zip(params, other, strict=True)]
    target = torch.rand(32, 40, 3, generator=torch.Generator().manual_seed(4))

    def run(ps):
        leaves = [t.clone().requires_grad_(True) for t in ps]
        xi = torch.zeros(6, requires_grad=True)
        out = rasterize(*leaves, se3_exp(xi) @ se3_exp(POSE), K, 40, 32, backend="fused", stats=True)
        ((out.color - target).abs().mean() + 0.1 * out.depth.mean()).backward()
        return out, [t.grad for t in leaves], xi.grad

    alone, g_alone, xi_alone = run(params)
    both_, g_both, xi_both = run(mixed)
    assert (both_.radius_px[1::2] == 0).all() and (both_.radius_px[0::2] > 0).sum() > 40
    for f in FIELDS:
        assert torch.equal(getattr(both_, f), getattr(alone, f)), f
    for f in ("coverage", "hit_count", "max_weight"):
        assert torch.equal(getattr(both_, f)[0::2], getattr(alone, f)), f
        assert (getattr(both_, f)[1::2] == 0).all(), f
    for ga, gb in zip(g_alone, g_both, strict=True):
        assert torch.equal(gb[0::2], ga) and (gb[1::2] == 0).all()
    assert torch.equal(xi_both, xi_alone) and xi_alone.abs().max() > 0


def test_gradients_under_a_loss_mask_match_torch():
    """The backward skips pixels no gradient reaches (tracking's silhouette mask); the pixels it
    does walk must still receive every contributor: gradients as the torch reference gives them."""
    *params, K = scene(seed=9)
    W, H = 40, 32
    target = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(5))
    mask = torch.zeros(H, W)
    mask[4:20, 3:29] = 1.0  # straddles tiles, leaves whole tiles without gradient

    def masked(backend):
        leaves = [t.clone().requires_grad_(True) for t in params]
        xi = torch.zeros(6, requires_grad=True)
        out = rasterize(*leaves, se3_exp(xi) @ se3_exp(POSE), K, W, H, backend=backend)
        (((out.color - target).abs().sum(-1) + out.depth) * mask).mean().backward()
        return [t.grad for t in leaves] + [xi.grad]

    for name, g, r in zip(
        ["means", "log_scales", "quats", "opacity", "colors", "pose"], masked("fused"), masked("torch"), strict=True
    ):
        assert r.abs().max() > 0, name
        torch.testing.assert_close(g, r, atol=2e-6, rtol=2e-3, msg=name)


def test_binning_orders_pairs_as_a_stable_depth_argsort():
    """The radix sort behind bin_pairs gives the pair list a stable comparison sort gives: ties by index,
    negative depths and -0.0 included (such depths are culled in a render, so only a direct call sees them)."""
    import numpy as np

    from bench.slam import raster_fused
    from bench.slam.raster_fused import binning

    g = torch.Generator().manual_seed(3)
    n, tiles_x, tiles_y = 4000, 9, 5
    for z in (
        torch.rand(n, generator=g) * 80 + 0.2,  # distinct depths
        torch.randint(-3, 4, (n,), generator=g).float(),
    ):  # mostly ties, negatives and zeros
        z[::7] = torch.where(z[::7] == 0, torch.tensor(-0.0), z[::7])
        x0, y0 = torch.randint(0, tiles_x, (n,), generator=g), torch.randint(0, tiles_y, (n,), generator=g)
        span = torch.randint(0, 3, (n, 2), generator=g)  # 0: an empty (culled) rectangle
        rect = torch.stack([x0, (x0 + span[:, 0]).clamp(max=tiles_x), y0, (y0 + span[:, 1]).clamp(max=tiles_y)], -1).to(
            torch.int32
        )
        tile_start, gid = raster_fused.bin_pairs(rect, z, tiles_x * tiles_y, tiles_x)
        order = torch.argsort(z, stable=True).to(torch.int32).numpy()
        ref_start, ref_gid = binning.bin_pairs_kernel(order, rect.numpy(), tiles_x * tiles_y, tiles_x, 1)
        assert gid.numel() > n // 2
        assert np.array_equal(tile_start.numpy(), ref_start)
        assert np.array_equal(gid.numpy(), ref_gid)
        for n_bands in (2, 3):  # bands of tile rows, one a thread: the same lists
            band_start, band_gid = binning.bin_pairs_kernel(order, rect.numpy(), tiles_x * tiles_y, tiles_x, n_bands)
            assert np.array_equal(band_start, ref_start) and np.array_equal(band_gid, ref_gid)


def test_peak_memory_grows_with_gaussian_count():
    """A fixed view rendered with N and 2N Gaussians: the fused peak follows the count."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "profiling"))
    from raster_bench import scene as bench_scene

    peaks = {}
    for n in (4000, 8000):
        params, K = bench_scene(n, 160, 96, torch.device("cpu"))
        probe = MemoryProbe(torch.device("cpu"))
        probe.start_window()
        out = rasterize(*params, torch.eye(4), K, 160, 96, backend="fused")
        (out.color.sum() + out.depth.sum()).backward()
        peaks[n] = probe.end_window()["torch_live_peak_mib"]
        probe.close()
        del out
    if peaks[4000] is None:
        pytest.skip("the live-tensor probe is unavailable here")
    assert peaks[8000] > 1.5 * peaks[4000]


def test_backend_choice():
    assert resolve_backend("auto", torch.device("cpu")) == "fused"
    from bench.slam.raster_gsplat import unavailable_reason

    assert resolve_backend("auto", torch.device("cuda")) == ("torch" if unavailable_reason() else "gsplat")
    with pytest.raises(ConfigError, match="found 'cuda_fast'"):
        resolve_backend("cuda_fast", torch.device("cpu"))
    with pytest.raises(ConfigError, match="runs on cpu tensors"):
        resolve_backend("fused", torch.device("cuda"))


def test_pixel_loops_compile_to_vector_code():
    """The compositing spans stay vectorised: a change that breaks one of the rules written above
    ``raster_fused.compositing.S_X`` passes every value test and is only slower, so the assembly is read here
    (compiled afresh, since numba cannot show the assembly of cached code)."""
    import re

    import llvmlite.binding as llvm
    import numpy as np
    from numba import njit

    from bench.slam.raster_fused import compositing as rf

    if "+avx2" not in llvm.get_host_cpu_features().flatten().split(","):
        pytest.skip("the host has no AVX2")
    flags = {k: v for k, v in rf.KERNEL_OPTIONS.items() if k != "cache"}
    f32, u64 = np.float32, np.uint64
    gaussian = [f32(v) for v in (0.0, 3.0, 1.0, 1.0, 1.0, 0.0, 1.0, 0.5, -5.0, 1.0, 1.0, 1.0, 1.0, 3.0)]
    rows = [f32(0.0), f32(16.0)]  # the backward also masks to the box's rows
    for span, size, args in (
        (rf._forward_span, rf.S_SIZE, gaussian),
        (rf._backward_span, rf.B_SIZE, gaussian[:2] + rows + gaussian[2:]),
    ):
        fn = njit(**flags)(span.py_func)
        fn(np.zeros(size, f32), u64(0), u64(16), *args)
        asm = fn.inspect_asm(fn.signatures[0])
        # packed float32 arithmetic on 8 lanes (AVX2) or 16 (AVX-512, which LLVM picks on hosts that
        # run it at full width, e.g. Zen 5)
        packed = re.findall(r"\bv\w+ps\s[^\n]*%[yz]mm", asm)
        assert len(packed) > 60, f"{span.__name__}: {len(packed)} packed AVX2/AVX-512 instructions"

    # the backward's span as composite_bwd calls it, whole pairs of rows: no scalar remainder loop (a scalar
    # copy of the loop body has dozens of scalar float ops; what is left is the sums' reductions and
    # the gradients computed from them)
    span = rf._backward_span

    @njit(**flags)
    def whole_rows(st, pairs, g, out):
        g0, g1, g2, g3, g4, g5, g6, g7, g8, g9, g10, g11, g12, g13, g14, g15 = g
        n = u64(pairs) << rf._UPAIR_SHIFT
        gr = span(st, u64(0), n, g0, g1, g2, g3, g4, g5, g6, g7, g8, g9, g10, g11, g12, g13, g14, g15)
        for m in range(10):
            out[m] = gr[m]

    whole_rows(np.zeros(rf.B_SIZE, f32), 2, tuple(gaussian[:2] + rows + gaussian[2:]), np.zeros(10, f32))
    asm = whole_rows.inspect_asm(whole_rows.signatures[0])
    scalar = re.findall(r"\bv(?:fn?m(?:add|sub)\d+|add|sub|mul|div|min|max)ss\b", asm)
    assert len(scalar) < 40, f"composite_bwd's span: {len(scalar)} scalar float32 instructions (a remainder loop?)"


_RENDER_TO = """
import sys, torch
from bench.slam.raster import rasterize
from bench.slam.se3 import se3_exp
g = torch.Generator().manual_seed(0)
n = 2000
means = torch.cat([torch.rand(n, 2, generator=g) * 8 - 4, torch.rand(n, 1, generator=g) * 10 + 3], 1)
params = [t.requires_grad_(True) for t in (means, torch.rand(n, 3, generator=g) - 3.5, torch.randn(n, 4, generator=g),
          torch.rand(n, generator=g), torch.rand(n, 3, generator=g))]
xi = torch.zeros(6, requires_grad=True)
K = torch.tensor([[60.0, 0, 48], [0, 60.0, 32], [0, 0, 1]])
out = rasterize(*params, se3_exp(xi) @ torch.eye(4), K, 96, 64, backend="fused", stats=True)
(out.color.square().mean() + out.depth.mean()).backward()
torch.save([out.color, out.depth, out.coverage, xi.grad] + [p.grad for p in params], sys.argv[1])
"""


@pytest.mark.slow
def test_a_process_that_compiles_the_kernels_repeats_one_that_loads_them(tmp_path):
    """Kernels compiled in the process that runs them rounded otherwise than the same kernels loaded
    from numba's cache: the first run after an install did not repeat. Both processes here start
    from an empty cache folder's state as a user's first and second run do."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    root = Path(__file__).resolve().parents[2]
    for name in ("first", "second"):
        subprocess.run([sys.executable, "-c", _RENDER_TO, str(tmp_path / f"{name}.pt")], env=env, cwd=root, check=True)
    first, second = torch.load(tmp_path / "first.pt"), torch.load(tmp_path / "second.pt")
    assert first[0].abs().max() > 0 and first[3].abs().max() > 0
    for a, b in zip(first, second, strict=True):
        assert torch.equal(a, b)


@pytest.mark.parametrize("W,H,seed", [(40, 32, 0), (33, 17, 1)])
def test_criteria_statistics_match_torch(W, H, seed):
    """The pruning criteria's statistics (rasterize(extra=...)): fused against the torch reference."""
    *params, _ = scene(seed=seed)
    K = torch.tensor([[0.75 * W, 0, W / 2 - 0.5], [0, 0.75 * W, H / 2 - 0.5], [0, 0, 1]])
    extra = ("weight_sum", "top1", "alpha_grad_sq")
    ref, got = both(params, K, W, H, stats=True, extra=extra, background=torch.tensor([0.1, 0.2, 0.3]))
    for f in ("weight_sum", "opacity_t_sum", "alpha_grad_sq"):
        torch.testing.assert_close(getattr(got, f), getattr(ref, f), atol=5e-4, rtol=1e-4, msg=f)
    for f in ("top1_count", "top1_after_count"):  # one per pixel with a contributor; a near-tie may flip
        assert getattr(got, f).dtype == torch.int64
        assert (getattr(got, f) - getattr(ref, f)).abs().sum() <= 2, f
        assert int(getattr(ref, f).sum()) == int((ref.alpha > 0).sum())
    assert ref.weight_sum.sum() > 1 and ref.alpha_grad_sq.sum() > 1


def test_criteria_statistics_only_when_asked():
    *params, _ = scene()
    W, H = 40, 32
    K = torch.tensor([[30.0, 0, 19.5], [0, 30.0, 15.5], [0, 0, 1]])
    for out in both(params, K, W, H, stats=True, extra=("top1",)):
        assert out.top1_count is not None and out.weight_sum is None and out.alpha_grad_sq is None
    for out in both(params, K, W, H, stats=True):
        assert out.top1_count is None and out.weight_sum is None
    with pytest.raises(ConfigError, match="expected among weight_sum, top1, alpha_grad_sq, found nope"):
        rasterize(*params, se3_exp(POSE), K, W, H, extra=("nope",))


def test_the_kernels_float32_constants_are_the_torch_backends() -> None:
    """raster_fused/constants.py holds float32 twins of raster's conventions; a change to one must reach the other."""
    import numpy as np

    from bench.slam import raster
    from bench.slam.raster_fused import constants

    assert constants.TILE == raster.TILE_PX
    for name in ("ALPHA_MIN", "ALPHA_MAX", "T_MIN", "LOWPASS_PX2"):
        assert getattr(constants, name) == np.float32(getattr(raster, name)), name
