"""The tiled rasterizer against a dense brute-force renderer with the same conventions."""

from __future__ import annotations

import math

import pytest
import torch

from bench.slam import raster
from bench.slam.raster import covariance3d, project, rasterize
from bench.slam.se3 import se3_exp


def brute_force(means, log_scales, quats, opac, colors, w2c, K, W, H):
    """Every pixel against every Gaussian, sorted by depth, no tiles except the 3-sigma tile culling."""
    cov3d = covariance3d(log_scales, quats)
    m2, cov2d, z = project(means, cov3d, w2c, K, W, H)
    inv = torch.linalg.inv(cov2d)
    order = torch.argsort(z.detach())
    m2, inv, z, opac, colors, cov2d = m2[order], inv[order], z[order], opac[order], colors[order], cov2d[order]
    ys, xs = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    pix = torch.stack([xs, ys], -1).reshape(-1, 2).float()  # [P, 2]
    d = pix[:, None, :] - m2[None]  # [P, N, 2]
    power = -0.5 * torch.einsum("pni,nij,pnj->pn", d, inv, d)
    alpha = torch.clamp(opac[None] * torch.exp(power), max=0.99)
    # 3-sigma tile culling, as the CUDA rasterizer does
    a, c = cov2d[:, 0, 0], cov2d[:, 1, 1]
    det = torch.linalg.det(cov2d)
    mid = 0.5 * (a + c)
    r = torch.ceil(3 * torch.sqrt(mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1)))).detach()
    tx, ty = (pix[:, 0] // 16)[:, None], (pix[:, 1] // 16)[:, None]
    md = m2.detach()
    in_rect = (
        (tx >= torch.floor((md[:, 0] - r) / 16))
        & (tx <= torch.floor((md[:, 0] + r) / 16))
        & (ty >= torch.floor((md[:, 1] - r) / 16))
        & (ty <= torch.floor((md[:, 1] + r) / 16))
    )
    keep = in_rect & (z[None] > 0.05) & (power <= 0) & (alpha >= 1 / 255)
    alpha = alpha * keep
    out_c, out_d, out_a = [], [], []
    for p in range(pix.shape[0]):
        T = torch.ones(())
        cc = torch.zeros(3)
        dd = torch.zeros(())
        for n in range(means.shape[0]):
            al = alpha[p, n]
            if al.item() == 0:
                continue
            if (T * (1 - al)).item() < 1e-4:
                break
            cc = cc + al * T * colors[n]
            dd = dd + al * T * z[n]
            T = T * (1 - al)
        out_c.append(cc)
        out_d.append(dd)
        out_a.append(1 - T)
    return torch.stack(out_c).reshape(H, W, 3), torch.stack(out_d).reshape(H, W), torch.stack(out_a).reshape(H, W)


def scene(n=12, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = torch.cat([torch.rand(n, 2, generator=g) * 2 - 1, torch.rand(n, 1, generator=g) * 3 + 2], 1)
    log_scales = torch.log(torch.rand(n, 3, generator=g) * 0.25 + 0.05)
    quats = torch.randn(n, 4, generator=g)
    opac = torch.rand(n, generator=g) * 0.9 + 0.05
    colors = torch.rand(n, 3, generator=g)
    K = torch.tensor([[30.0, 0, 19.5], [0, 30.0, 15.5], [0, 0, 1]])
    return means, log_scales, quats, opac, colors, K


@pytest.mark.parametrize("seed", [0, 1])
def test_values_match_brute_force(seed):
    means, ls, q, o, c, K = scene(seed=seed)
    w2c = se3_exp(torch.tensor([0.05, -0.02, 0.1, 0.02, -0.03, 0.01]))
    W, H = 40, 32  # partial tiles on the right and bottom
    out = rasterize(means, ls, q, o, c, w2c, K, W, H)
    ref_c, ref_d, ref_a = brute_force(means, ls, q, o, c, w2c, K, W, H)
    assert out.alpha.max() > 0.5  # the scene is actually visible
    torch.testing.assert_close(out.color, ref_c, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(out.depth, ref_d, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(out.alpha, ref_a, atol=1e-5, rtol=1e-4)


def test_gradients_match_brute_force_including_pose():
    means, ls, q, o, c, K = scene(n=8, seed=3)
    W, H = 32, 32
    leaves = [t.clone().requires_grad_(True) for t in (means, ls, q, o, c)]
    xi = torch.zeros(6, requires_grad=True)
    base = se3_exp(torch.tensor([0.05, -0.02, 0.1, 0.02, -0.03, 0.01]))
    target = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(9))

    def loss(render):
        col, dep, _ = render
        return (col - target).abs().mean() + 0.1 * dep.mean()

    out = rasterize(*leaves, se3_exp(xi) @ base, K, W, H)
    loss((out.color, out.depth, out.alpha)).backward()
    got = [t.grad.clone() for t in leaves] + [xi.grad.clone()]
    for t in [*leaves, xi]:
        t.grad = None
    loss(brute_force(*leaves, se3_exp(xi) @ base, K, W, H)).backward()
    ref = [t.grad for t in leaves] + [xi.grad]
    for name, g, r in zip(["means", "log_scales", "quats", "opacity", "colors", "pose"], got, ref, strict=True):
        assert r.abs().max() > 0, name
        torch.testing.assert_close(g, r, atol=1e-5, rtol=1e-3, msg=name)


def test_per_gaussian_outputs():
    means, ls, q, o, c, K = scene(seed=4)
    W, H = 40, 32
    w2c = torch.eye(4)
    out = rasterize(means, ls, q, o, c, w2c, K, W, H, stats=True)
    # tile of the projected centre comes from the real projection
    m2 = out.means2d
    for i in range(len(means)):
        x, y = m2[i].tolist()
        if 0 <= x < W and 0 <= y < H:
            assert out.tile_id[i] == int(y // 16) * out.tiles_xy[0] + int(x // 16)
        else:
            assert out.tile_id[i] == -1
    assert len(set(out.tile_id.tolist())) > 2
    # coverage: brute-force sum of o*exp(power) over all image pixels (3-sigma truncation ~1%)
    inv = torch.linalg.inv(out.cov2d)
    ys, xs = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    pix = torch.stack([xs, ys], -1).reshape(-1, 2).float()
    d = pix[:, None] - m2[None]
    brute = (o[None] * torch.exp(-0.5 * torch.einsum("pni,nij,pnj->pn", d, inv, d))).sum(0)
    torch.testing.assert_close(out.coverage, brute, rtol=0.02, atol=1e-3)
    assert (out.hit_count >= 0).all() and out.hit_count.sum() > 0
    assert ((out.max_weight >= 0) & (out.max_weight <= 0.99)).all()
    # a Gaussian well inside the image: analytic area o * 2 pi sqrt(det) ~ exact coverage
    inside = [
        i for i in range(len(means)) if 12 < m2[i, 0] < W - 12 and 12 < m2[i, 1] < H - 12 and out.radius_px[i] < 10
    ]
    for i in inside:
        analytic = o[i] * 2 * math.pi * torch.sqrt(torch.linalg.det(out.cov2d[i]))
        assert abs(analytic - brute[i]) / analytic < 0.05


def test_chunking_does_not_change_result(monkeypatch):
    means, ls, q, o, c, K = scene(seed=5)
    w2c = torch.eye(4)
    full = rasterize(means, ls, q, o, c, w2c, K, 40, 32)
    monkeypatch.setattr(raster, "CHUNK_ELEMS", 300)
    small = rasterize(means, ls, q, o, c, w2c, K, 40, 32)
    torch.testing.assert_close(full.color, small.color)


def _one_pixel(opac, colors, bg=None, backend="torch", extra=("weight_sum", "top1", "alpha_grad_sq")):
    """Gaussians centred on the single pixel of a 1x1 image (G = 1 there, so alpha = o), front to back."""
    n = len(opac)
    means = torch.tensor([[0.0, 0.0, 1.0 + i] for i in range(n)])
    log_scales = torch.full((n, 3), math.log(1e-3))
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
    K = torch.tensor([[10.0, 0, 0], [0, 10.0, 0], [0, 0, 1]])
    return rasterize(
        means,
        log_scales,
        quats,
        opac,
        colors,
        torch.eye(4),
        K,
        1,
        1,
        background=bg,
        stats=True,
        backend=backend,
        extra=extra,
    )


@pytest.mark.parametrize("backend", ["torch", "fused"])
def test_criteria_statistics_known_answer(backend):
    """docs/criteria.md, Example E, pixel p2: (A, alpha 0.6), (C, alpha 0.5) front to back, colours 1 and 0.5
    on one channel, background 0: w = (0.6, 0.2), o T = (0.6, 0.2), A tops the pixel by alpha T and by
    alpha T_after (0.24 vs 0.1), (o dI/dalpha)^2 = (0.2025, 0.01); with grey colours on 3 channels x 9."""
    opac = torch.tensor([0.6, 0.5])
    out = _one_pixel(opac, torch.tensor([[1.0, 0, 0], [0.5, 0, 0]]), backend=backend)
    torch.testing.assert_close(out.weight_sum, torch.tensor([0.6, 0.2]))
    torch.testing.assert_close(out.opacity_t_sum, torch.tensor([0.6, 0.2]))
    assert out.top1_count.tolist() == [1, 0] and out.top1_after_count.tolist() == [1, 0]
    torch.testing.assert_close(out.alpha_grad_sq, torch.tensor([0.2025, 0.01]))
    grey = _one_pixel(opac, torch.tensor([[1.0] * 3, [0.5] * 3]), backend=backend)
    torch.testing.assert_close(grey.alpha_grad_sq, 9 * torch.tensor([0.2025, 0.01]))


@pytest.mark.parametrize("bg", [0.0, 0.3])
def test_alpha_grad_sq_is_the_gradient_of_the_image_sum(bg):
    """(o dI/dalpha)^2 in closed form against autograd: with alpha = o G and G = 1, o dI/dalpha = o dI/do."""
    opac = torch.tensor([0.7, 0.4, 0.55, 0.3], requires_grad=True)
    colors = torch.tensor([[0.9, 0.1, 0.3], [0.2, 0.8, 0.5], [0.6, 0.6, 0.1], [0.3, 0.2, 0.9]])
    out = _one_pixel(opac, colors, bg=torch.full((3,), bg))
    out.color.sum().backward()
    torch.testing.assert_close(out.alpha_grad_sq, (opac.detach() * opac.grad) ** 2, rtol=1e-5, atol=1e-7)
