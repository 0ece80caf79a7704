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
