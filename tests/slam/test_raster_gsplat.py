"""The gsplat backend against the torch reference, on the scenes of ``profiling/raster_bench.py``.

On CUDA with gsplat installed: the real gsplat against the reference on the same device, values,
statistics and gradients (parameters and pose). Elsewhere: the backend's own code run over
``gsplat_standin`` (gsplat's rules in torch, CPU), so CI exercises it without a GPU.

Tolerances (``assert_agree``): gsplat bins a footprint of up to 3.33 sigma per axis and clamps
alpha at 0.999, the reference a ceil(3 sigma_max) square at 0.99 (the backend's docstring), so
pixels at the rim of a footprint differ by a faint Gaussian's contribution; everything else is
float32 rounding in another order (gsplat compiles with fast math).
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest
import torch

from bench.errors import ConfigError
from bench.slam.raster import rasterize, resolve_backend
from bench.slam.se3 import se3_exp

ROOT = Path(__file__).resolve().parents[2]
POSE = torch.tensor([0.01, -0.02, 0.03, 0.01, -0.01, 0.02])
CUDA_POINTS = [(2000, 96, 64), (20000, 320, 192), (50000, 640, 384)]  # raster_bench's range, small to large
CPU_POINTS = [(2000, 96, 64), (5000, 160, 96)]
STANDIN_CASE = ("aniso", 2000, 96, 64, False)  # kind, n, W, H, antialiased: one stand-in case

# image: max |diff| and mean |diff|; depth in m
IMAGE_TOL = {"color": (1e-2, 1e-4), "alpha": (1e-2, 1e-4), "depth": (0.1, 1e-3)}
STAT_REL = 1e-2  # coverage, max weight (relative L2 norm of the difference), hit counts (relative L1)
GRAD_REL = 2e-2  # relative L2 norm of the gradient difference, per parameter, pose and screen means
GRAD_COS = 0.999


def _raster_bench():
    spec = importlib.util.spec_from_file_location("raster_bench", ROOT / "profiling" / "raster_bench.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def render_and_grads(params, K, W, H, backend, device, antialiased=False):
    """Outputs (stats on) and the gradients of a fixed loss: [means, log_scales, quats, opacity, colors,
    pose, screen means]."""
    for p in params:
        p.grad = None
    xi = POSE.clone().to(device).requires_grad_(True)
    out = rasterize(
        *params, se3_exp(xi), K, W, H, stats=True, depth_far_m=60.0, backend=backend, antialiased=antialiased
    )
    out.means2d.retain_grad()
    target = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(1)).to(device)
    loss = (out.color - target).abs().mean() + 0.1 * out.depth.mean() + out.alpha.mean()
    loss.backward()
    return out, [p.grad.clone() for p in params] + [xi.grad.clone(), out.means2d.grad.clone()]


def assert_agree(ref, got, ref_grads, got_grads):
    for f, (max_tol, mean_tol) in IMAGE_TOL.items():
        d = (getattr(got, f) - getattr(ref, f)).abs()
        assert d.max() <= max_tol and d.mean() <= mean_tol, f"{f}: max {d.max():.3g}, mean {d.mean():.3g}"
    both = (ref.radius_px > 0) & (got.radius_px > 0)
    assert both.float().mean() > 0.99
    torch.testing.assert_close(got.means2d[both], ref.means2d[both], atol=1e-3, rtol=0)
    torch.testing.assert_close(got.depths, ref.depths, atol=1e-4, rtol=1e-5)
    assert (got.tile_id == ref.tile_id).float().mean() > 0.999
    for f in ("coverage", "max_weight"):
        a, b = getattr(got, f).float(), getattr(ref, f).float()
        assert (a - b).norm() <= STAT_REL * b.norm(), f
    assert (got.hit_count - ref.hit_count).abs().sum() <= STAT_REL * ref.hit_count.sum()
    names = ["means", "log_scales", "quats", "opacity", "colors", "pose", "means2d"]
    scale = ref_grads[0].norm()
    for name, g, r in zip(names, got_grads, ref_grads, strict=True):
        if r.norm() <= 1e-6 * scale:  # isotropic Gaussians: no rotation gradient, up to rounding
            assert g.norm() <= 1e-3 * scale, name
            continue
        rel = float((g - r).norm() / r.norm())
        cos = float((g * r).sum() / (g.norm() * r.norm()))
        assert rel <= GRAD_REL and cos >= GRAD_COS, f"{name}: relative difference {rel:.3g}, cosine {cos:.6f}"


def test_same_tile_and_threshold_as_the_reference():
    from bench.slam import raster, raster_gsplat

    assert raster_gsplat.TILE_PX == raster.TILE_PX and raster_gsplat.ALPHA_MIN == raster.ALPHA_MIN


def test_gsplat_on_cpu_is_one_config_error():
    with pytest.raises(ConfigError, match="runs on cuda tensors"):
        resolve_backend("gsplat", torch.device("cpu"))


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("kind", ["iso", "aniso"])
@pytest.mark.parametrize("n,W,H", CPU_POINTS)
def test_backend_code_over_the_standin_agrees_with_reference(monkeypatch, kind, n, W, H, antialiased):
    sys.path.insert(0, str(Path(__file__).parent))
    import gsplat_standin

    monkeypatch.setitem(sys.modules, "gsplat", gsplat_standin)
    monkeypatch.setattr("bench.slam.raster_gsplat.unavailable_reason", lambda: None)
    monkeypatch.setattr("bench.slam.raster.resolve_backend", lambda backend, device: backend)
    params, K = _raster_bench().scene(n, W, H, torch.device("cpu"), kind=kind)
    ref, ref_grads = render_and_grads(params, K, W, H, "torch", "cpu", antialiased)
    got, got_grads = render_and_grads(params, K, W, H, "gsplat", "cpu", antialiased)
    assert_agree(ref, got, ref_grads, got_grads)


def test_nothing_in_view_over_the_standin(monkeypatch):
    sys.path.insert(0, str(Path(__file__).parent))
    import gsplat_standin

    monkeypatch.setitem(sys.modules, "gsplat", gsplat_standin)
    monkeypatch.setattr("bench.slam.raster.resolve_backend", lambda backend, device: backend)
    params, K = _raster_bench().scene(200, 32, 32, torch.device("cpu"))
    w2c = torch.diag(torch.tensor([1.0, 1.0, -1.0, 1.0]))  # every Gaussian behind the camera
    out = rasterize(*params, w2c, K, 32, 32, stats=True, backend="gsplat")
    assert (out.alpha == 0).all() and (out.depth == 0).all() and not out.color.requires_grad
    assert (out.radius_px == 0).all() and (out.tile_id == -1).all() and out.hit_count.sum() == 0


def _gsplat_reason() -> str | None:
    from bench.slam.raster_gsplat import unavailable_reason

    return unavailable_reason()


cuda_gsplat = pytest.mark.skipif(
    not torch.cuda.is_available() or importlib.util.find_spec("gsplat") is None,
    reason="needs a CUDA device and gsplat (pip install 'pocketbench[gpu]'); CI has neither",
)


@cuda_gsplat
def test_auto_picks_gsplat_on_cuda():
    assert _gsplat_reason() is None
    assert resolve_backend("auto", torch.device("cuda")) == "gsplat"


@cuda_gsplat
@pytest.mark.parametrize("kind", ["iso", "aniso"])
@pytest.mark.parametrize("n,W,H", CUDA_POINTS)
def test_gsplat_agrees_with_reference_on_cuda(kind, n, W, H):
    dev = torch.device("cuda")
    params, K = _raster_bench().scene(n, W, H, dev, kind=kind)
    ref, ref_grads = render_and_grads(params, K, W, H, "torch", dev)
    got, got_grads = render_and_grads(params, K, W, H, "gsplat", dev)
    assert_agree(ref, got, ref_grads, got_grads)


@cuda_gsplat
def test_gsplat_nothing_in_view_on_cuda():
    dev = torch.device("cuda")
    params, K = _raster_bench().scene(200, 32, 32, dev)
    w2c = torch.diag(torch.tensor([1.0, 1.0, -1.0, 1.0], device=dev))
    out = rasterize(*params, w2c, K, 32, 32, stats=True, backend="gsplat")
    assert (out.alpha == 0).all() and (out.radius_px == 0).all() and out.hit_count.sum() == 0


def test_criteria_statistics_on_gsplat_are_one_config_error(monkeypatch):
    """The pruning criteria's statistics (rasterize(extra=...)) exist in the torch and fused backends only."""
    from bench.slam import raster

    monkeypatch.setattr(raster, "resolve_backend", lambda backend, device: "gsplat")
    n = 4
    with pytest.raises(ConfigError, match=r"^slam.raster_backend=gsplat: statistics top1, weight_sum are not "):
        raster.rasterize(
            torch.rand(n, 3) + 2,
            torch.full((n, 3), -3.0),
            torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
            torch.full((n,), 0.5),
            torch.rand(n, 3),
            torch.eye(4),
            torch.eye(3),
            8,
            8,
            extra=("weight_sum", "top1"),
        )


def _stats_scene(device: str, seed: int = 0):
    """Screen means, conics and opacities of a random 45x37 px scene with 0-40 pairs a tile, some tiles deep in
    near-opaque Gaussians so the transmittance stop is reached (gsplat's packed layout: pairs grouped by tile)."""
    g = torch.Generator().manual_seed(seed)
    W, H, M = 45, 37, 80
    tiles_x, tiles_y = (W + 15) // 16, (H + 15) // 16
    means = torch.rand(M, 2, generator=g) * torch.tensor([W, H])
    L = torch.randn(M, 2, 2, generator=g) * 0.6
    inv = torch.linalg.inv(L @ L.transpose(1, 2) + 0.5 * torch.eye(2))
    conic = torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], -1)
    opacity = torch.where(torch.rand(M, generator=g) < 0.5, 0.995, torch.rand(M, generator=g))
    per_tile = torch.randint(0, 41, (tiles_x * tiles_y,), generator=g)
    gid = torch.cat([torch.randperm(M, generator=g)[:k] for k in per_tile.tolist()])
    args = [t.to(device) for t in (means, conic, opacity, gid, per_tile)]
    return args, tiles_x, W, H


@pytest.mark.parametrize("strict", [True, False])
def test_triton_statistics_agree_with_the_torch_chunks(strict):
    """slam.gsplat_stats=triton against pair_stats (the torch chunks), on CUDA; without one, under Triton's
    interpreter where triton is installed (it is not a dependency: skipped elsewhere)."""
    pytest.importorskip("triton")
    from bench.slam import gsplat_stats
    from bench.slam.raster_gsplat import GSPLAT_ALPHA_MAX, pair_stats

    device = "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cpu" and os.environ.get("TRITON_INTERPRET") != "1":
        pytest.skip("no CUDA device: run with TRITON_INTERPRET=1 (Triton's interpreter) to test the kernel on the CPU")
    for seed in range(3):
        args, tiles_x, W, H = _stats_scene(device, seed)
        want = pair_stats(*args, tiles_x, W, H, GSPLAT_ALPHA_MAX, strict_stop=strict)
        got = gsplat_stats.pair_stats_triton(*args, tiles_x, W, H, GSPLAT_ALPHA_MAX, strict_stop=strict)
        cov, hits, maxw = (t.cpu() for t in got)
        assert torch.equal(hits, want[1].cpu())
        assert torch.allclose(cov, want[0].cpu(), rtol=1e-5, atol=1e-6)
        assert torch.allclose(maxw, want[2].cpu(), rtol=1e-5, atol=1e-6)
        assert int(want[1].sum()) > 0 and float(want[2].max()) > 0.5  # the scene composites something


def test_triton_statistics_unavailable_is_one_config_error(monkeypatch):
    """slam.gsplat_stats=triton where it cannot run: one ConfigError line; auto falls back to torch."""
    from bench.slam import gsplat_stats
    from bench.slam.raster_gsplat import stats_impl

    monkeypatch.setattr(gsplat_stats, "unavailable_reason", lambda: "no CUDA device")
    with pytest.raises(ConfigError, match="slam.gsplat_stats=triton: no CUDA device"):
        stats_impl("triton")
    assert stats_impl("auto") == "torch" and stats_impl("torch") == "torch"
    # where Triton can run, CPU tensors (the stand-in tests' gsplat on the CPU) still take the torch chunks
    monkeypatch.setattr(gsplat_stats, "unavailable_reason", lambda: None)
    assert stats_impl("auto", torch.device("cpu")) == "torch" and stats_impl("triton", torch.device("cpu")) == "torch"
    assert stats_impl("auto", torch.device("cuda")) == "triton"


def test_standin_statistics_take_the_torch_chunks_where_triton_runs(monkeypatch):
    """The stand-in tests pass CPU tensors through the gsplat backend; on a machine with CUDA and Triton (the GPU
    check's) `auto` must not hand them to the Triton kernel (the first H200 check failed 8 tests so)."""
    from bench.slam import gsplat_stats

    monkeypatch.setattr(gsplat_stats, "unavailable_reason", lambda: None)

    def refuse(*a, **k):
        raise AssertionError("the Triton kernel got CPU tensors")

    monkeypatch.setattr(gsplat_stats, "pair_stats_triton", refuse)
    test_backend_code_over_the_standin_agrees_with_reference(monkeypatch, *STANDIN_CASE)
