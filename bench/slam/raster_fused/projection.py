"""Projection: world Gaussians to screen-space means, 2-D covariances, depths and tile rectangles, and its gradient."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from bench.slam.raster_fused.constants import F32, TILE

PROJECT_BLOCK = 256  # Gaussians per block of the projection's backward (one set of scratch matrices each)


@njit(cache=True, inline="always")
def _rotmat(qw, qx, qy, qz):  # pragma: no cover - compiled
    return (
        F32(1.0) - F32(2.0) * (qy * qy + qz * qz),
        F32(2.0) * (qx * qy - qw * qz),
        F32(2.0) * (qx * qz + qw * qy),
        F32(2.0) * (qx * qy + qw * qz),
        F32(1.0) - F32(2.0) * (qx * qx + qz * qz),
        F32(2.0) * (qy * qz - qw * qx),
        F32(2.0) * (qx * qz - qw * qy),
        F32(2.0) * (qy * qz + qw * qx),
        F32(1.0) - F32(2.0) * (qx * qx + qy * qy),
    )


@njit(cache=True, inline="always")
def _to_camera(means, i, rc, tc):  # pragma: no cover - compiled
    """Camera-frame position of Gaussian i (the backward recomputes it rather than storing it)."""
    mw0, mw1, mw2 = means[i, 0], means[i, 1], means[i, 2]
    return (
        rc[0, 0] * mw0 + rc[0, 1] * mw1 + rc[0, 2] * mw2 + tc[0],
        rc[1, 0] * mw0 + rc[1, 1] * mw1 + rc[1, 2] * mw2 + tc[1],
        rc[2, 0] * mw0 + rc[2, 1] * mw1 + rc[2, 2] * mw2 + tc[2],
    )


@njit(cache=True, inline="always")
def _jacobian_limits(fx, fy, width, height):  # pragma: no cover - compiled
    """3DGS clamps the Jacobian's lever arm at 1.3x the half field of view (as ``raster.project``)."""
    return F32(1.3) * (F32(0.5) * F32(width) / fx), F32(1.3) * (F32(0.5) * F32(height) / fy)


@njit(parallel=True, cache=True)
def project_fwd(
    means,
    log_scales,
    quats,
    rc,
    tc,
    cam,
    width,
    height,
    near_m,
    tiles_x,
    tiles_y,
    m2,
    cov,
    z_out,
    rect,
    radius_px,
    tile_id,
):  # pragma: no cover - compiled
    """EWA projection as ``raster.project`` computes it, plus culling and the tile rectangle.

    cam: (fx, fy, cx, cy); cov [N, 3] = (a, b, c) of the screen covariance incl. the 0.3 px low-pass,
    zero for a Gaussian culled by its centre (behind the near plane or outside the widened frustum).
    """
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lim_x, lim_y = _jacobian_limits(fx, fy, width, height)
    for i in prange(means.shape[0]):
        px, py, pz = _to_camera(means, i, rc, tc)
        zs = pz if abs(pz) >= F32(1e-6) else F32(1e-6)
        mx = fx * px / zs + cx
        my = fy * py / zs + cy
        m2[i, 0], m2[i, 1] = mx, my
        z_out[i] = pz
        if not (
            pz > near_m
            and abs(mx - cx) < F32(1.3) * F32(0.5) * F32(width)
            and abs(my - cy) < F32(1.3) * F32(0.5) * F32(height)
        ):
            # culled by its centre (behind the near plane or outside the widened frustum): on a long
            # drive most of the map, whose screen covariance nothing reads, so it is left at zero
            cov[i, 0] = cov[i, 1] = cov[i, 2] = F32(0.0)
            rect[i, 0] = rect[i, 1] = rect[i, 2] = rect[i, 3] = 0
            radius_px[i] = 0
            tile_id[i] = -1
            continue
        tx = min(max(px / zs, -lim_x), lim_x) * zs
        ty = min(max(py / zs, -lim_y), lim_y) * zs
        j00, j02 = fx / zs, -fx * tx / (zs * zs)
        j11, j12 = fy / zs, -fy * ty / (zs * zs)
        # T = J Rc  [2, 3]
        t00 = j00 * rc[0, 0] + j02 * rc[2, 0]
        t01 = j00 * rc[0, 1] + j02 * rc[2, 1]
        t02 = j00 * rc[0, 2] + j02 * rc[2, 2]
        t10 = j11 * rc[1, 0] + j12 * rc[2, 0]
        t11 = j11 * rc[1, 1] + j12 * rc[2, 1]
        t12 = j11 * rc[1, 2] + j12 * rc[2, 2]
        qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
        qn = max(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), F32(1e-12))
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotmat(qw / qn, qx / qn, qy / qn, qz / qn)
        s0, s1, s2 = np.exp(log_scales[i, 0]), np.exp(log_scales[i, 1]), np.exp(log_scales[i, 2])
        # U = T M with M = R diag(s): cov2d = U U^T
        u00 = (t00 * r00 + t01 * r10 + t02 * r20) * s0
        u01 = (t00 * r01 + t01 * r11 + t02 * r21) * s1
        u02 = (t00 * r02 + t01 * r12 + t02 * r22) * s2
        u10 = (t10 * r00 + t11 * r10 + t12 * r20) * s0
        u11 = (t10 * r01 + t11 * r11 + t12 * r21) * s1
        u12 = (t10 * r02 + t11 * r12 + t12 * r22) * s2
        a = u00 * u00 + u01 * u01 + u02 * u02 + F32(0.3)
        b = u00 * u10 + u01 * u11 + u02 * u12
        c = u10 * u10 + u11 * u11 + u12 * u12 + F32(0.3)
        cov[i, 0], cov[i, 1], cov[i, 2] = a, b, c
        det = a * c - b * b
        mid = F32(0.5) * (a + c)
        lam = mid + np.sqrt(max(mid * mid - det, F32(0.1)))
        radius = np.ceil(F32(3.0) * np.sqrt(lam))
        front = det > F32(0.0)  # and the centre tests above
        x0 = int(min(max(np.floor((mx - radius) / F32(TILE)), F32(0.0)), F32(tiles_x)))
        x1 = int(min(max(np.floor((mx + radius) / F32(TILE)) + F32(1.0), F32(0.0)), F32(tiles_x)))
        y0 = int(min(max(np.floor((my - radius) / F32(TILE)), F32(0.0)), F32(tiles_y)))
        y1 = int(min(max(np.floor((my + radius) / F32(TILE)) + F32(1.0), F32(0.0)), F32(tiles_y)))
        visible = front and x1 > x0 and y1 > y0
        rect[i, 0], rect[i, 1], rect[i, 2], rect[i, 3] = x0, (x1 if visible else x0), y0, y1
        radius_px[i] = int(radius) if visible else 0
        if front and mx >= F32(0.0) and mx < F32(width) and my >= F32(0.0) and my < F32(height):
            tile_id[i] = int(min(my, F32(height - 1)) // F32(TILE)) * tiles_x + int(
                min(mx, F32(width - 1)) // F32(TILE)
            )
        else:
            tile_id[i] = -1


@njit(parallel=True, cache=True)
def project_bwd(
    means,
    log_scales,
    quats,
    rc,
    tc,
    cam,
    width,
    height,
    g_m2,
    g_cov,
    g_z,
    gaussians,
    g_means,
    g_log_scales,
    g_quats,
    g_pose,
):  # pragma: no cover - compiled
    """The chain rule of ``project_fwd`` per Gaussian; g_pose [N, 12] holds each Gaussian's share of
    d/d(Rc row-major, tc), reduced afterwards in a fixed order. Without ``gaussians`` (tracking: only
    the pose is optimised) the gradients of means, log-scales and quaternions are left unwritten.

    The small per-Gaussian matrices are allocated once per block of Gaussians: an allocation per
    Gaussian cost more than its arithmetic."""
    fx, fy = cam[0], cam[1]
    lim_x, lim_y = _jacobian_limits(fx, fy, width, height)
    n = means.shape[0]
    for blk in prange((n + PROJECT_BLOCK - 1) // PROJECT_BLOCK):
        t = np.empty((2, 3), np.float32)
        rg = np.empty((3, 3), np.float32)
        sc = np.empty(3, np.float32)
        mm = np.empty((3, 3), np.float32)  # M = Rg diag(s)
        sig = np.empty((3, 3), np.float32)  # Sigma = M M^T
        ts = np.empty((2, 3), np.float32)  # T Sigma
        gt = np.empty((2, 3), np.float32)
        gsig = np.empty((3, 3), np.float32)
        grg = np.empty((3, 3), np.float32)
        for i in range(blk * PROJECT_BLOCK, min(n, (blk + 1) * PROJECT_BLOCK)):
            if (
                g_m2[i, 0] == 0
                and g_m2[i, 1] == 0
                and g_cov[i, 0] == 0
                and g_cov[i, 1] == 0
                and g_cov[i, 2] == 0
                and g_z[i] == 0
            ):
                # nothing flows back (out of view: on a long drive most of the map): every product below is 0
                for k in range(12):
                    g_pose[i, k] = F32(0.0)
                if gaussians:
                    for k in range(3):
                        g_means[i, k] = F32(0.0)
                        g_log_scales[i, k] = F32(0.0)
                    for k in range(4):
                        g_quats[i, k] = F32(0.0)
                continue
            mw0, mw1, mw2 = means[i, 0], means[i, 1], means[i, 2]
            px, py, pz = _to_camera(means, i, rc, tc)
            z_ok = abs(pz) >= F32(1e-6)
            zs = pz if z_ok else F32(1e-6)
            ux, uy = px / zs, py / zs
            clamp_x = ux < -lim_x or ux > lim_x
            clamp_y = uy < -lim_y or uy > lim_y
            tx = min(max(ux, -lim_x), lim_x) * zs
            ty = min(max(uy, -lim_y), lim_y) * zs
            zs2 = zs * zs
            j00, j02 = fx / zs, -fx * tx / zs2
            j11, j12 = fy / zs, -fy * ty / zs2
            for k in range(3):
                t[0, k] = j00 * rc[0, k] + j02 * rc[2, k]
                t[1, k] = j11 * rc[1, k] + j12 * rc[2, k]
            qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
            qn = max(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), F32(1e-12))
            nw, nx, ny, nz = qw / qn, qx / qn, qy / qn, qz / qn
            rg[0, 0], rg[0, 1], rg[0, 2], rg[1, 0], rg[1, 1], rg[1, 2], rg[2, 0], rg[2, 1], rg[2, 2] = _rotmat(
                nw, nx, ny, nz
            )
            for k in range(3):
                sc[k] = np.exp(log_scales[i, k])
            for j in range(3):
                for k in range(3):
                    mm[j, k] = rg[j, k] * sc[k]
            for j in range(3):
                for k in range(3):
                    sig[j, k] = mm[j, 0] * mm[k, 0] + mm[j, 1] * mm[k, 1] + mm[j, 2] * mm[k, 2]
            # symmetric upstream gradient of the 2x2 screen covariance (b is read once, off the diagonal)
            gs00, gs01, gs11 = g_cov[i, 0], F32(0.5) * g_cov[i, 1], g_cov[i, 2]
            # dL/dT = 2 Gs T Sigma ; dL/dSigma = T^T Gs T ; dL/dM = 2 dL/dSigma M
            for r in range(2):
                for k in range(3):
                    ts[r, k] = t[r, 0] * sig[0, k] + t[r, 1] * sig[1, k] + t[r, 2] * sig[2, k]
            for k in range(3):
                gt[0, k] = F32(2.0) * (gs00 * ts[0, k] + gs01 * ts[1, k])
                gt[1, k] = F32(2.0) * (gs01 * ts[0, k] + gs11 * ts[1, k])
            if gaussians:
                for j in range(3):
                    for k in range(3):
                        gsig[j, k] = t[0, j] * (gs00 * t[0, k] + gs01 * t[1, k]) + t[1, j] * (
                            gs01 * t[0, k] + gs11 * t[1, k]
                        )
                for k in range(3):
                    gsk = F32(0.0)
                    for j in range(3):
                        gm = F32(2.0) * (gsig[j, 0] * mm[0, k] + gsig[j, 1] * mm[1, k] + gsig[j, 2] * mm[2, k])
                        grg[j, k] = gm * sc[k]
                        gsk += gm * rg[j, k]
                    g_log_scales[i, k] = gsk * sc[k]
                d = grg
                gw = F32(2.0) * (
                    -nz * d[0, 1] + ny * d[0, 2] + nz * d[1, 0] - nx * d[1, 2] - ny * d[2, 0] + nx * d[2, 1]
                )
                gx = F32(2.0) * (
                    ny * d[0, 1]
                    + nz * d[0, 2]
                    + ny * d[1, 0]
                    - F32(2.0) * nx * d[1, 1]
                    - nw * d[1, 2]
                    + nz * d[2, 0]
                    + nw * d[2, 1]
                    - F32(2.0) * nx * d[2, 2]
                )
                gy = F32(2.0) * (
                    -F32(2.0) * ny * d[0, 0]
                    + nx * d[0, 1]
                    + nw * d[0, 2]
                    + nx * d[1, 0]
                    + nz * d[1, 2]
                    - nw * d[2, 0]
                    + nz * d[2, 1]
                    - F32(2.0) * ny * d[2, 2]
                )
                gz = F32(2.0) * (
                    -F32(2.0) * nz * d[0, 0]
                    - nw * d[0, 1]
                    + nx * d[0, 2]
                    + nw * d[1, 0]
                    - F32(2.0) * nz * d[1, 1]
                    + ny * d[1, 2]
                    + nx * d[2, 0]
                    + ny * d[2, 1]
                )
                dot = nw * gw + nx * gx + ny * gy + nz * gz
                g_quats[i, 0] = (gw - nw * dot) / qn
                g_quats[i, 1] = (gx - nx * dot) / qn
                g_quats[i, 2] = (gy - ny * dot) / qn
                g_quats[i, 3] = (gz - nz * dot) / qn
            # T = J Rc: dL/dJ = dL/dT Rc^T, dL/dRc += J^T dL/dT
            gj00 = gt[0, 0] * rc[0, 0] + gt[0, 1] * rc[0, 1] + gt[0, 2] * rc[0, 2]
            gj02 = gt[0, 0] * rc[2, 0] + gt[0, 1] * rc[2, 1] + gt[0, 2] * rc[2, 2]
            gj11 = gt[1, 0] * rc[1, 0] + gt[1, 1] * rc[1, 1] + gt[1, 2] * rc[1, 2]
            gj12 = gt[1, 0] * rc[2, 0] + gt[1, 1] * rc[2, 1] + gt[1, 2] * rc[2, 2]
            for k in range(3):
                g_pose[i, k] = j00 * gt[0, k]
                g_pose[i, 3 + k] = j11 * gt[1, k]
                g_pose[i, 6 + k] = j02 * gt[0, k] + j12 * gt[1, k]
            # camera-space point: from J (through zs, tx, ty), the projected mean and z
            gmx, gmy = g_m2[i, 0], g_m2[i, 1]
            g_tx = gj02 * (-fx / zs2)
            g_ty = gj12 * (-fy / zs2)
            g_zs = (
                gj00 * (-fx / zs2)
                + gj02 * (F32(2.0) * fx * tx / (zs2 * zs))
                + gj11 * (-fy / zs2)
                + gj12 * (F32(2.0) * fy * ty / (zs2 * zs))
                - (gmx * fx * px + gmy * fy * py) / zs2
            )
            gpx = gmx * fx / zs
            gpy = gmy * fy / zs
            if clamp_x:  # tx = +-lim_x zs
                g_zs += g_tx * (lim_x if ux > F32(0.0) else -lim_x)
            else:
                gpx += g_tx
            if clamp_y:
                g_zs += g_ty * (lim_y if uy > F32(0.0) else -lim_y)
            else:
                gpy += g_ty
            gpz = g_z[i] + (g_zs if z_ok else F32(0.0))
            if gaussians:
                for k in range(3):
                    g_means[i, k] = rc[0, k] * gpx + rc[1, k] * gpy + rc[2, k] * gpz
            g_pose[i, 0] += gpx * mw0
            g_pose[i, 1] += gpx * mw1
            g_pose[i, 2] += gpx * mw2
            g_pose[i, 3] += gpy * mw0
            g_pose[i, 4] += gpy * mw1
            g_pose[i, 5] += gpy * mw2
            g_pose[i, 6] += gpz * mw0
            g_pose[i, 7] += gpz * mw1
            g_pose[i, 8] += gpz * mw2
            g_pose[i, 9] = gpx
            g_pose[i, 10] = gpy
            g_pose[i, 11] = gpz


@njit(cache=True)
def sum_rows(vals, out):  # pragma: no cover - compiled
    """out[j] = sum_i vals[i, j] in row order (a fixed order, unlike a threaded reduction)."""
    for i in range(vals.shape[0]):
        for j in range(vals.shape[1]):
            out[j] += vals[i, j]
