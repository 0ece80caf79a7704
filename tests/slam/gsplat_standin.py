"""A CPU stand-in for the four gsplat 1.5.3 calls ``bench/slam/raster_gsplat.py`` makes, in torch.

Why: CI has no GPU, and the backend's own code (packing, the half-pixel shift, the [N] scatter, the
depth channel, the statistics) must run in CI. The stand-in follows the rules of gsplat's CUDA
kernels as read in its 1.5.3 sources (ProjectionEWA3DGSPacked.cu, IntersectTile.cu,
RasterizeToPixels3DGSFwd.cu): packed outputs, per-axis radii of min(3.33, sqrt(2 ln(255 o))) sigma,
culling by z, opacity and the box missing the image, pixel centres at +0.5, alpha clamped at 0.999,
a pixel stopping before T would reach 1e-4. It is no evidence that gsplat itself behaves so: the
CUDA tests (``test_raster_gsplat.py``, GPU only) compare the real gsplat with the reference.
"""

from __future__ import annotations

import math

import torch

from bench.slam.raster import covariance3d

ALPHA_THRESHOLD = 1.0 / 255.0


def fully_fused_projection(
    means,
    covars,
    quats,
    scales,
    viewmats,
    Ks,
    width,
    height,
    eps2d=0.3,
    near_plane=0.01,
    far_plane=1e10,
    packed=False,
    opacities=None,
    calc_compensations=False,
):
    assert covars is None and packed
    R, t = viewmats[0, :3, :3], viewmats[0, :3, 3]
    K = Ks[0]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    p = means @ R.T + t
    x, y, z = p.unbind(-1)
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    tx = z * torch.clamp(x / z, -(cx / fx + 0.3 * tan_x), (width - cx) / fx + 0.3 * tan_x)
    ty = z * torch.clamp(y / z, -(cy / fy + 0.3 * tan_y), (height - cy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(z)
    J = torch.stack(
        [torch.stack([fx / z, zero, -fx * tx / z**2], -1), torch.stack([zero, fy / z, -fy * ty / z**2], -1)], -2
    )
    T = J @ R
    raw = T @ covariance3d(torch.log(scales), quats) @ T.transpose(1, 2)  # [N, 2, 2] before the low-pass
    cov = raw + eps2d * torch.eye(2)
    m2 = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    conics = torch.stack([cov[:, 1, 1], -cov[:, 0, 1], cov[:, 0, 0]], -1) / det[:, None]
    with torch.no_grad():
        extend = torch.clamp(
            torch.sqrt(2 * torch.log(opacities.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD)), max=3.33
        )
        rx = torch.ceil(extend * torch.sqrt(cov[:, 0, 0]))
        ry = torch.ceil(extend * torch.sqrt(cov[:, 1, 1]))
        ok = (z >= near_plane) & (z <= far_plane) & (det > 0) & (opacities >= ALPHA_THRESHOLD)
        ok &= (m2[:, 0] + rx > 0) & (m2[:, 0] - rx < width) & (m2[:, 1] + ry > 0) & (m2[:, 1] - ry < height)
        gid = ok.nonzero().flatten()
    radii = torch.stack([rx, ry], -1)[gid].int()
    zeros = torch.zeros_like(gid)
    comps = None
    if calc_compensations:  # gsplat: sqrt(max(0, det_orig / det_blur))
        det_raw = raw[:, 0, 0] * raw[:, 1, 1] - raw[:, 0, 1] ** 2
        comps = (det_raw / det).clamp_min(1e-12).sqrt()[gid]
    return zeros, zeros, gid, radii, m2[gid], z[gid], conics[gid], comps


@torch.no_grad()
def isect_tiles(
    means2d,
    radii,
    depths,
    tile_size,
    tile_width,
    tile_height,
    packed=False,
    n_images=None,
    image_ids=None,
    gaussian_ids=None,
):
    tmin = torch.floor((means2d - radii) / tile_size).long()
    tmax = torch.ceil((means2d + radii) / tile_size).long()
    tmin[:, 0].clamp_(0, tile_width), tmin[:, 1].clamp_(0, tile_height)
    tmax[:, 0].clamp_(0, tile_width), tmax[:, 1].clamp_(0, tile_height)
    span = (tmax - tmin).clamp_min(0)
    counts = span[:, 0] * span[:, 1]
    idx = torch.repeat_interleave(torch.arange(means2d.shape[0]), counts)
    local = torch.arange(idx.numel()) - (torch.cumsum(counts, 0) - counts)[idx]
    sx = span[idx, 0].clamp_min(1)
    tile = (tmin[idx, 1] + local // sx) * tile_width + tmin[idx, 0] + local % sx
    depth_bits = depths.contiguous().view(torch.int32).long()[idx]  # positive floats sort as their bits
    isect_ids = (tile << 32) | depth_bits
    isect_ids, order = torch.sort(isect_ids, stable=True)
    return counts.int(), isect_ids, idx[order].int()


@torch.no_grad()
def isect_offset_encode(isect_ids, n_images, tile_width, tile_height):
    counts = torch.bincount(isect_ids >> 32, minlength=tile_width * tile_height)
    return (torch.cumsum(counts, 0) - counts).int().reshape(1, tile_height, tile_width)


def rasterize_to_pixels(
    means2d, conics, colors, opacities, width, height, tile_size, isect_offsets, flatten_ids, packed=False
):
    """Differentiable front-to-back compositing over the pairs, with gsplat's rules (autograd backward)."""
    n_pairs = flatten_ids.numel()
    per_tile = torch.diff(isect_offsets.reshape(-1).long(), append=torch.tensor([n_pairs]))
    tile = torch.repeat_interleave(torch.arange(per_tile.numel()), per_tile)
    g = flatten_ids.long()
    ly, lx = torch.meshgrid(torch.arange(tile_size), torch.arange(tile_size), indexing="ij")
    tiles_x = isect_offsets.shape[-1]
    px = (tile % tiles_x)[:, None] * tile_size + lx.reshape(1, -1)
    py = (tile // tiles_x)[:, None] * tile_size + ly.reshape(1, -1)
    valid = (px < width) & (py < height)
    dx, dy = px + 0.5 - means2d[g, 0:1], py + 0.5 - means2d[g, 1:2]
    a, b, c = conics[g].unbind(-1)
    sigma = 0.5 * (a[:, None] * dx * dx + c[:, None] * dy * dy) + b[:, None] * dx * dy
    raw = opacities[g][:, None] * torch.exp(-sigma)
    ok = ((raw >= ALPHA_THRESHOLD) & valid).detach()
    alpha = torch.where(ok, raw.clamp(max=0.999), torch.zeros_like(raw))
    log1m = torch.log1p(-alpha)
    cum = torch.cumsum(log1m.double(), 0)
    first = torch.searchsorted(tile, tile)
    log_t = (cum - (cum[first] - log1m.double()[first])).float()
    keep = ok & (log_t > math.log(1e-4)).detach()
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    log1m = torch.log1p(-alpha)
    cum = torch.cumsum(log1m.double(), 0)
    log_t_excl = (cum - cum[first] + log1m.double()[first] - log1m.double()).float()
    w = alpha * torch.exp(log_t_excl)  # [P, 256]
    lin = torch.where(valid, py * width + px, torch.full_like(px, width * height)).reshape(-1)
    img = torch.zeros(width * height + 1, colors.shape[1]).index_add(
        0, lin, (w[:, :, None] * colors[g][:, None, :]).reshape(-1, colors.shape[1])
    )
    acc = torch.zeros(width * height + 1).index_add(0, lin, w.reshape(-1))
    return img[:-1].reshape(1, height, width, -1), acc[:-1].reshape(1, height, width, 1)
