"""The torch face of the kernels: ``project`` and ``composite`` as differentiable ``torch.autograd.Function``s."""

from __future__ import annotations

import numba
import numpy as np
import torch

from bench.slam.raster_fused.compositing import (
    G_SIZE,
    composite_bwd,
    composite_fwd,
    pack,
    reduce_stats,
    reduce_sum,
    tile_schedule,
)
from bench.slam.raster_fused.constants import N_FEAT
from bench.slam.raster_fused.kernel_cache import load_from_cache
from bench.slam.raster_fused.projection import project_bwd, project_fwd, sum_rows
from bench.slam.raster_fused.threads import set_threads
from bench.slam.raster_fused.view import gather_view, scatter_view


class _Project(torch.autograd.Function):
    """World Gaussians -> screen (means2d [N, 2], cov [N, 3], z [N]) plus culling and tile rectangles."""

    @staticmethod
    def forward(ctx, means, log_scales, quats, w2c, cam, width, height, near_m, tiles_x, tiles_y):
        # a Gaussian's projection costs a fraction of a pair's compositing, so it goes parallel later
        set_threads(int(means.shape[0]) // 2)
        mw, ls, q = (t.detach().float().contiguous() for t in (means, log_scales, quats))
        rc = w2c.detach()[:3, :3].float().contiguous()
        tc = w2c.detach()[:3, 3].float().contiguous()
        n = mw.shape[0]
        m2 = torch.empty(n, 2)
        cov = torch.empty(n, 3)
        z = torch.empty(n)
        rect = torch.empty(n, 4, dtype=torch.int32)
        radius_px = torch.empty(n, dtype=torch.int64)
        tile_id = torch.empty(n, dtype=torch.int64)
        project_fwd(
            mw.numpy(),
            ls.numpy(),
            q.numpy(),
            rc.numpy(),
            tc.numpy(),
            cam.numpy(),
            width,
            height,
            np.float32(near_m),
            tiles_x,
            tiles_y,
            m2.numpy(),
            cov.numpy(),
            z.numpy(),
            rect.numpy(),
            radius_px.numpy(),
            tile_id.numpy(),
        )
        ctx.save_for_backward(mw, ls, q, rc, tc, cam)
        ctx.dims = (width, height)
        ctx.mark_non_differentiable(rect, radius_px, tile_id)
        return m2, cov, z, rect, radius_px, tile_id

    @staticmethod
    def backward(ctx, g_m2, g_cov, g_z, *_):
        mw, ls, q, rc, tc, cam = ctx.saved_tensors
        set_threads(int(mw.shape[0]) // 2)
        width, height = ctx.dims
        n = mw.shape[0]
        g_m2 = torch.zeros(n, 2) if g_m2 is None else g_m2.float().contiguous()
        g_cov = torch.zeros(n, 3) if g_cov is None else g_cov.float().contiguous()
        g_z = torch.zeros(n) if g_z is None else g_z.float().contiguous()
        g_means, g_ls, g_q = torch.empty(n, 3), torch.empty(n, 3), torch.empty(n, 4)
        gaussians = any(ctx.needs_input_grad[:3])
        pose = ctx.needs_input_grad[3]  # mapping: the keyframe's pose is fixed, so no [N, 12] rows to fill and sum
        g_pose_rows = torch.empty(n if pose else 0, 12)  # [N, 12]
        project_bwd(
            mw.numpy(),
            ls.numpy(),
            q.numpy(),
            rc.numpy(),
            tc.numpy(),
            cam.numpy(),
            width,
            height,
            g_m2.numpy(),
            g_cov.numpy(),
            g_z.numpy(),
            gaussians,
            pose,
            g_means.numpy(),
            g_ls.numpy(),
            g_q.numpy(),
            g_pose_rows.numpy(),
        )
        g_w2c = None
        if pose:
            g_pose = torch.zeros(12)
            sum_rows(g_pose_rows.numpy(), g_pose.numpy())
            g_w2c = torch.zeros(4, 4)
            g_w2c[:3, :3] = g_pose[:9].reshape(3, 3)
            g_w2c[:3, 3] = g_pose[9:]
        if not gaussians:
            return None, None, None, g_w2c, None, None, None, None, None, None
        return g_means, g_ls, g_q, g_w2c, None, None, None, None, None, None


def project(
    means: torch.Tensor,
    log_scales: torch.Tensor,
    quats: torch.Tensor,
    w2c: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    near_m: float,
    tiles_x: int,
    tiles_y: int,
) -> tuple[torch.Tensor, ...]:
    """means2d [N, 2], cov [N, 3] (a, b, c), z [N] (differentiable in means, log-scales, quats and the
    pose w2c [4, 4]); rect [N, 4] int32, radius_px [N], tile_id [N] as ``raster._front`` defines them."""
    load_from_cache()
    cam = torch.stack([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]).detach().float().cpu()
    return _Project.apply(means, log_scales, quats, w2c, cam, width, height, near_m, tiles_x, tiles_y)


class _Composite(torch.autograd.Function):
    """Differentiable compositing of the Gaussians in view (``vis`` [V], indices into the map's N): per-pixel
    outputs acc [H*W, 4] and T [H*W]. It takes the map's [N] tensors, and gathers those in view, their conic
    and antialiasing factor, and scatters their gradients back, in compiled kernels (``view``)."""

    @staticmethod
    def forward(
        ctx, means2d, cov, opac, colors, z, vis, gid, tile_start, width, height, tiles_x, stats, antialiased, far
    ):
        set_threads(int(gid.shape[0]))
        m2, cv, op, col, zz = (t.detach().float().contiguous() for t in (means2d, cov, opac, colors, z))
        n, v = m2.shape[0], vis.shape[0]
        m2_v, inv_v, op_v = torch.empty(v, 2), torch.empty(v, 3), torch.empty(v)  # [V, 2], [V, 3], [V]
        feat_v, fac_v = torch.empty(v, N_FEAT), torch.empty(v)  # [V, 4], [V]
        far32 = np.float32(far)
        gather_view(
            vis.numpy(),
            m2.numpy(),
            cv.numpy(),
            op.numpy(),
            col.numpy(),
            zz.numpy(),
            antialiased,
            far32,
            m2_v.numpy(),
            inv_v.numpy(),
            op_v.numpy(),
            feat_v.numpy(),
            fac_v.numpy(),
        )
        hw = width * height
        acc = torch.empty(hw, N_FEAT, dtype=torch.float32)  # [H*W, 4]
        t_final = torch.empty(hw, dtype=torch.float32)  # [H*W]
        last = torch.empty(hw, dtype=torch.int64)  # [H*W] pair index of the last contributor, -1 none
        n_pairs = int(gid.shape[0]) if stats else 0
        pair_cov = torch.empty(n_pairs, dtype=torch.float32)
        pair_hits = torch.empty(n_pairs, dtype=torch.int32)
        pair_maxw = torch.empty(n_pairs, dtype=torch.float32)
        gp = torch.empty(v, G_SIZE, dtype=torch.float32)  # [V, 16]
        pack(m2_v.numpy(), inv_v.numpy(), op_v.numpy(), feat_v.numpy(), gp.numpy())
        del m2_v, inv_v, op_v, feat_v
        order, bounds = tile_schedule(tile_start.numpy(), numba.get_num_threads())
        composite_fwd(
            gid.numpy(),
            tile_start.numpy(),
            gp.numpy(),
            width,
            height,
            tiles_x,
            stats,
            order,
            bounds,
            acc.numpy(),
            t_final.numpy(),
            last.numpy(),
            pair_cov.numpy(),
            pair_hits.numpy(),
            pair_maxw.numpy(),
        )
        coverage = torch.zeros(n if stats else 0, dtype=torch.float32)  # [N]: zero out of view
        hit_count = torch.zeros(n if stats else 0, dtype=torch.int64)
        max_weight = torch.zeros(n if stats else 0, dtype=torch.float32)
        if stats:
            cov_v = torch.zeros(v, dtype=torch.float32)
            hits_v = torch.zeros(v, dtype=torch.int64)
            maxw_v = torch.zeros(v, dtype=torch.float32)
            reduce_stats(
                gid.numpy(),
                pair_cov.numpy(),
                pair_hits.numpy(),
                pair_maxw.numpy(),
                cov_v.numpy(),
                hits_v.numpy(),
                maxw_v.numpy(),
            )
            coverage[vis], hit_count[vis], max_weight[vis] = cov_v, hits_v, maxw_v
        del pair_cov, pair_hits, pair_maxw
        ctx.save_for_backward(gp, gid, tile_start, t_final, last, vis, cv, op, zz, fac_v)
        ctx.dims = (width, height, tiles_x, antialiased, far32)
        ctx.mark_non_differentiable(coverage, hit_count, max_weight)
        return acc, t_final, coverage, hit_count, max_weight

    @staticmethod
    def backward(ctx, g_acc, g_t, *_):
        gp, gid, tile_start, t_final, last, vis, cv, op, zz, fac_v = ctx.saved_tensors
        set_threads(int(gid.shape[0]))
        width, height, tiles_x, antialiased, far32 = ctx.dims
        hw = width * height
        g_acc = torch.zeros(hw, N_FEAT) if g_acc is None else g_acc.contiguous().to(torch.float32)
        g_t = torch.zeros(hw) if g_t is None else g_t.contiguous().to(torch.float32)
        pair_grad = torch.empty(gid.shape[0], 10, dtype=torch.float32)  # [P, 10]
        order, bounds = tile_schedule(tile_start.numpy(), numba.get_num_threads())
        composite_bwd(
            gid.numpy(),
            tile_start.numpy(),
            gp.numpy(),
            width,
            height,
            tiles_x,
            order,
            bounds,
            t_final.numpy(),
            last.numpy(),
            g_acc.numpy(),
            g_t.numpy(),
            pair_grad.numpy(),
        )
        grad_v = torch.zeros(gp.shape[0], 10, dtype=torch.float32)  # [V, 10]
        reduce_sum(gid.numpy(), pair_grad.numpy(), grad_v.numpy())
        del pair_grad
        n = cv.shape[0]
        want_op, want_col = ctx.needs_input_grad[2], ctx.needs_input_grad[3]
        g_m2, g_cov, g_z = torch.zeros(n, 2), torch.zeros(n, 3), torch.zeros(n)  # [N, 2], [N, 3], [N]
        g_op, g_col = torch.zeros(n if want_op else 0), torch.zeros(n if want_col else 0, 3)  # [N], [N, 3]
        scatter_view(
            vis.numpy(),
            grad_v.numpy(),
            cv.numpy(),
            op.numpy(),
            zz.numpy(),
            far32,
            antialiased,
            fac_v.numpy(),
            g_m2.numpy(),
            g_cov.numpy(),
            g_op.numpy(),
            g_col.numpy(),
            g_z.numpy(),
        )
        return (
            g_m2,
            g_cov,
            g_op if want_op else None,
            g_col if want_col else None,
            g_z,
            *(None,) * 9,
        )


def composite(
    means2d: torch.Tensor,
    cov: torch.Tensor,
    opac: torch.Tensor,
    colors: torch.Tensor,
    z: torch.Tensor,
    vis: torch.Tensor,
    gid: torch.Tensor,
    tile_start: torch.Tensor,
    width: int,
    height: int,
    tiles_x: int,
    stats: bool,
    antialiased: bool = False,
    depth_far_m: float | None = None,
) -> tuple[torch.Tensor, ...]:
    """acc [H*W, 4] (colour, painted depth), T_final [H*W], and (stats) coverage, hit_count, max_weight [N] (zero
    out of view) of the Gaussians ``vis`` [V] in view; differentiable in the map's means2d [N, 2], screen
    covariances cov [N, 3] (a, b, c), opacities opac [N], colours colors [N, 3] and depths z [N]. The opacities
    are scaled by ``raster.antialias_compensation`` where ``antialiased``; a Gaussian at ``depth_far_m`` or
    farther paints depth 0 (``raster._paint_depth``). ``gid`` holds pair indices into ``vis``."""
    far = np.inf if depth_far_m is None else depth_far_m
    return _Composite.apply(
        means2d, cov, opac, colors, z, vis, gid, tile_start, width, height, tiles_x, stats, antialiased, far
    )
