"""Projection: world Gaussians to screen-space means, 2-D covariances, depths and tile rectangles, and its gradient."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from bench.slam.raster_fused.constants import F32, LOWPASS_PX2, TILE


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
def _jacobian_rows(j00, j02, j11, j12, rc):  # pragma: no cover - compiled
    """T = J Rc [2, 3] (row-major), J the projection's Jacobian [[j00, 0, j02], [0, j11, j12]]."""
    return (
        j00 * rc[0, 0] + j02 * rc[2, 0],
        j00 * rc[0, 1] + j02 * rc[2, 1],
        j00 * rc[0, 2] + j02 * rc[2, 2],
        j11 * rc[1, 0] + j12 * rc[2, 0],
        j11 * rc[1, 1] + j12 * rc[2, 1],
        j11 * rc[1, 2] + j12 * rc[2, 2],
    )


@njit(cache=True, inline="always")
def _unit_quat(quats, i):  # pragma: no cover - compiled
    """Gaussian i's quaternion normalised (w, x, y, z) and its norm (at least 1e-12)."""
    qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
    qn = max(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), F32(1e-12))
    return qw / qn, qx / qn, qy / qn, qz / qn, qn


@njit(cache=True, inline="always")
def _scales(log_scales, i):  # pragma: no cover - compiled
    return np.exp(log_scales[i, 0]), np.exp(log_scales[i, 1]), np.exp(log_scales[i, 2])


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
        t00, t01, t02, t10, t11, t12 = _jacobian_rows(j00, j02, j11, j12, rc)  # T = J Rc [2, 3]
        nw, nx, ny, nz, _ = _unit_quat(quats, i)
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotmat(nw, nx, ny, nz)
        s0, s1, s2 = _scales(log_scales, i)
        # U = T M with M = R diag(s): cov2d = U U^T
        u00 = (t00 * r00 + t01 * r10 + t02 * r20) * s0
        u01 = (t00 * r01 + t01 * r11 + t02 * r21) * s1
        u02 = (t00 * r02 + t01 * r12 + t02 * r22) * s2
        u10 = (t10 * r00 + t11 * r10 + t12 * r20) * s0
        u11 = (t10 * r01 + t11 * r11 + t12 * r21) * s1
        u12 = (t10 * r02 + t11 * r12 + t12 * r22) * s2
        a = u00 * u00 + u01 * u01 + u02 * u02 + LOWPASS_PX2
        b = u00 * u10 + u01 * u11 + u02 * u12
        c = u10 * u10 + u11 * u11 + u12 * u12 + LOWPASS_PX2
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
    pose,
    g_means,
    g_log_scales,
    g_quats,
    g_pose,
):  # pragma: no cover - compiled
    """The chain rule of ``project_fwd`` per Gaussian; g_pose [N, 12] holds each Gaussian's share of
    d/d(Rc row-major, tc), reduced afterwards in a fixed order. Without ``gaussians`` (tracking: only
    the pose is optimised) the gradients of means, log-scales and quaternions are left unwritten;
    without ``pose`` (mapping: the keyframe's pose is fixed) g_pose is.

    Every small matrix is a set of scalars (t_rk is row r, column k of T), so that they live in
    registers; each entry is the expression, in the order, of the matrix products they stand for."""
    fx, fy = cam[0], cam[1]
    lim_x, lim_y = _jacobian_limits(fx, fy, width, height)
    n = means.shape[0]
    for i in prange(n):
        if (
            g_m2[i, 0] == 0
            and g_m2[i, 1] == 0
            and g_cov[i, 0] == 0
            and g_cov[i, 1] == 0
            and g_cov[i, 2] == 0
            and g_z[i] == 0
        ):
            # nothing flows back (out of view: on a long drive most of the map): every product below is 0
            if pose:
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
        t00, t01, t02, t10, t11, t12 = _jacobian_rows(j00, j02, j11, j12, rc)  # T = J Rc [2, 3]
        nw, nx, ny, nz, qn = _unit_quat(quats, i)
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotmat(nw, nx, ny, nz)
        s0, s1, s2 = _scales(log_scales, i)
        # M = Rg diag(s)
        m00, m01, m02 = r00 * s0, r01 * s1, r02 * s2
        m10, m11, m12 = r10 * s0, r11 * s1, r12 * s2
        m20, m21, m22 = r20 * s0, r21 * s1, r22 * s2
        # Sigma = M M^T (symmetric: sig_jk = sig_kj, each computed as its own product)
        sg00 = m00 * m00 + m01 * m01 + m02 * m02
        sg01 = m00 * m10 + m01 * m11 + m02 * m12
        sg02 = m00 * m20 + m01 * m21 + m02 * m22
        sg10 = m10 * m00 + m11 * m01 + m12 * m02
        sg11 = m10 * m10 + m11 * m11 + m12 * m12
        sg12 = m10 * m20 + m11 * m21 + m12 * m22
        sg20 = m20 * m00 + m21 * m01 + m22 * m02
        sg21 = m20 * m10 + m21 * m11 + m22 * m12
        sg22 = m20 * m20 + m21 * m21 + m22 * m22
        # symmetric upstream gradient of the 2x2 screen covariance (b is read once, off the diagonal)
        gs00, gs01, gs11 = g_cov[i, 0], F32(0.5) * g_cov[i, 1], g_cov[i, 2]
        # dL/dT = 2 Gs T Sigma ; dL/dSigma = T^T Gs T ; dL/dM = 2 dL/dSigma M
        ts00 = t00 * sg00 + t01 * sg10 + t02 * sg20
        ts01 = t00 * sg01 + t01 * sg11 + t02 * sg21
        ts02 = t00 * sg02 + t01 * sg12 + t02 * sg22
        ts10 = t10 * sg00 + t11 * sg10 + t12 * sg20
        ts11 = t10 * sg01 + t11 * sg11 + t12 * sg21
        ts12 = t10 * sg02 + t11 * sg12 + t12 * sg22
        gt00 = F32(2.0) * (gs00 * ts00 + gs01 * ts10)
        gt01 = F32(2.0) * (gs00 * ts01 + gs01 * ts11)
        gt02 = F32(2.0) * (gs00 * ts02 + gs01 * ts12)
        gt10 = F32(2.0) * (gs01 * ts00 + gs11 * ts10)
        gt11 = F32(2.0) * (gs01 * ts01 + gs11 * ts11)
        gt12 = F32(2.0) * (gs01 * ts02 + gs11 * ts12)
        if gaussians:
            # Gs T columns: c_k = (gs00 t0k + gs01 t1k, gs01 t0k + gs11 t1k); gsig_jk = t0j c_k0 + t1j c_k1
            c00, c01 = gs00 * t00 + gs01 * t10, gs01 * t00 + gs11 * t10
            c10, c11 = gs00 * t01 + gs01 * t11, gs01 * t01 + gs11 * t11
            c20, c21 = gs00 * t02 + gs01 * t12, gs01 * t02 + gs11 * t12
            gg00, gg01, gg02 = t00 * c00 + t10 * c01, t00 * c10 + t10 * c11, t00 * c20 + t10 * c21
            gg10, gg11, gg12 = t01 * c00 + t11 * c01, t01 * c10 + t11 * c11, t01 * c20 + t11 * c21
            gg20, gg21, gg22 = t02 * c00 + t12 * c01, t02 * c10 + t12 * c11, t02 * c20 + t12 * c21
            # column k of dL/dM: gm_jk = 2 (gsig_j0 m0k + gsig_j1 m1k + gsig_j2 m2k)
            gm00 = F32(2.0) * (gg00 * m00 + gg01 * m10 + gg02 * m20)
            gm10 = F32(2.0) * (gg10 * m00 + gg11 * m10 + gg12 * m20)
            gm20 = F32(2.0) * (gg20 * m00 + gg21 * m10 + gg22 * m20)
            gm01 = F32(2.0) * (gg00 * m01 + gg01 * m11 + gg02 * m21)
            gm11 = F32(2.0) * (gg10 * m01 + gg11 * m11 + gg12 * m21)
            gm21 = F32(2.0) * (gg20 * m01 + gg21 * m11 + gg22 * m21)
            gm02 = F32(2.0) * (gg00 * m02 + gg01 * m12 + gg02 * m22)
            gm12 = F32(2.0) * (gg10 * m02 + gg11 * m12 + gg12 * m22)
            gm22 = F32(2.0) * (gg20 * m02 + gg21 * m12 + gg22 * m22)
            g_log_scales[i, 0] = (gm00 * r00 + gm10 * r10 + gm20 * r20) * s0
            g_log_scales[i, 1] = (gm01 * r01 + gm11 * r11 + gm21 * r21) * s1
            g_log_scales[i, 2] = (gm02 * r02 + gm12 * r12 + gm22 * r22) * s2
            # dL/dRg = dL/dM diag(s)
            d00, d01, d02 = gm00 * s0, gm01 * s1, gm02 * s2
            d10, d11, d12 = gm10 * s0, gm11 * s1, gm12 * s2
            d20, d21, d22 = gm20 * s0, gm21 * s1, gm22 * s2
            gw = F32(2.0) * (-nz * d01 + ny * d02 + nz * d10 - nx * d12 - ny * d20 + nx * d21)
            gx = F32(2.0) * (
                ny * d01
                + nz * d02
                + ny * d10
                - F32(2.0) * nx * d11
                - nw * d12
                + nz * d20
                + nw * d21
                - F32(2.0) * nx * d22
            )
            gy = F32(2.0) * (
                -F32(2.0) * ny * d00
                + nx * d01
                + nw * d02
                + nx * d10
                + nz * d12
                - nw * d20
                + nz * d21
                - F32(2.0) * ny * d22
            )
            gz = F32(2.0) * (
                -F32(2.0) * nz * d00
                - nw * d01
                + nx * d02
                + nw * d10
                - F32(2.0) * nz * d11
                + ny * d12
                + nx * d20
                + ny * d21
            )
            dot = nw * gw + nx * gx + ny * gy + nz * gz
            g_quats[i, 0] = (gw - nw * dot) / qn
            g_quats[i, 1] = (gx - nx * dot) / qn
            g_quats[i, 2] = (gy - ny * dot) / qn
            g_quats[i, 3] = (gz - nz * dot) / qn
        # T = J Rc: dL/dJ = dL/dT Rc^T, dL/dRc += J^T dL/dT
        gj00 = gt00 * rc[0, 0] + gt01 * rc[0, 1] + gt02 * rc[0, 2]
        gj02 = gt00 * rc[2, 0] + gt01 * rc[2, 1] + gt02 * rc[2, 2]
        gj11 = gt10 * rc[1, 0] + gt11 * rc[1, 1] + gt12 * rc[1, 2]
        gj12 = gt10 * rc[2, 0] + gt11 * rc[2, 1] + gt12 * rc[2, 2]
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
        if pose:
            g_pose[i, 0] = j00 * gt00 + gpx * mw0
            g_pose[i, 1] = j00 * gt01 + gpx * mw1
            g_pose[i, 2] = j00 * gt02 + gpx * mw2
            g_pose[i, 3] = j11 * gt10 + gpy * mw0
            g_pose[i, 4] = j11 * gt11 + gpy * mw1
            g_pose[i, 5] = j11 * gt12 + gpy * mw2
            g_pose[i, 6] = (j02 * gt00 + j12 * gt10) + gpz * mw0
            g_pose[i, 7] = (j02 * gt01 + j12 * gt11) + gpz * mw1
            g_pose[i, 8] = (j02 * gt02 + j12 * gt12) + gpz * mw2
            g_pose[i, 9] = gpx
            g_pose[i, 10] = gpy
            g_pose[i, 11] = gpz


@njit(cache=True)
def sum_rows(vals, out):  # pragma: no cover - compiled
    """out[j] = sum_i vals[i, j] in row order (a fixed order, unlike a threaded reduction)."""
    for i in range(vals.shape[0]):
        for j in range(vals.shape[1]):
            out[j] += vals[i, j]
