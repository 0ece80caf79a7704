"""SE(3)/SO(3) maths on torch tensors, differentiable everywhere including the identity.

Conventions: a twist ``xi = [v, w]`` (translation part first), poses as [4, 4] homogeneous
matrices, quaternions ``quat_wxyz``. Camera frames follow OpenCV (x right, y down, z forward).
Only what the harness uses lives here; the inverses that only tests need (``se3_log``,
``rotmat_to_quat``) live in ``tests/slam/test_se3.py``.
"""

from __future__ import annotations

import torch

_SMALL = 1e-8


def hat(w: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix of ``w`` [..., 3] -> [..., 3, 3]."""
    zero = torch.zeros_like(w[..., 0])
    wx, wy, wz = w.unbind(-1)
    return torch.stack(
        [
            torch.stack([zero, -wz, wy], -1),
            torch.stack([wz, zero, -wx], -1),
            torch.stack([-wy, wx, zero], -1),
        ],
        -2,
    )


def _coeffs(theta2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """sin(t)/t, (1-cos t)/t^2, (t-sin t)/t^3 with Taylor series near zero (finite gradients)."""
    small = theta2 < _SMALL
    t2 = torch.where(small, torch.ones_like(theta2), theta2)
    t = t2.sqrt()
    a = torch.where(small, 1 - theta2 / 6, torch.sin(t) / t)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(t)) / t2)
    c = torch.where(small, 1 / 6 - theta2 / 120, (t - torch.sin(t)) / (t2 * t))
    return a, b, c


def so3_exp(w: torch.Tensor) -> torch.Tensor:
    """Rodrigues: axis-angle [..., 3] -> rotation [..., 3, 3]."""
    theta2 = (w * w).sum(-1)[..., None, None]
    a, b, _ = _coeffs(theta2)
    W = hat(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand(W.shape)
    return eye + a * W + b * (W @ W)


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """Rotation [..., 3, 3] -> axis-angle [..., 3] (no gradient needed: used for reporting)."""
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1.0, 1.0)
    theta = torch.acos(cos)
    v = torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = torch.sin(theta)
    scale = torch.where(sin.abs() < 1e-6, 0.5 + theta**2 / 12, theta / (2 * sin.clamp_min(1e-12)))
    return v * scale[..., None]


def se3_exp(xi: torch.Tensor) -> torch.Tensor:
    """Twist [..., 6] = [v, w] -> pose [..., 4, 4]."""
    v, w = xi[..., :3], xi[..., 3:]
    theta2 = (w * w).sum(-1)[..., None, None]
    a, b, c = _coeffs(theta2)
    W = hat(w)
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device).expand(W.shape)
    W2 = W @ W
    R = eye + a * W + b * W2
    V = eye + b * W + c * W2
    t = (V @ v[..., None])[..., 0]
    top = torch.cat([R, t[..., None]], -1)
    bottom = torch.zeros(*xi.shape[:-1], 1, 4, dtype=xi.dtype, device=xi.device)
    bottom[..., 0, 3].fill_(1.0)  # fill_, not `= 1`: setting a CUDA element from Python copies from the host
    return torch.cat([top, bottom], -2)


def inverse(T: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid poses [..., 4, 4] without a general matrix inverse."""
    R, t = T[..., :3, :3], T[..., :3, 3:]
    Rt = R.transpose(-1, -2)
    out = torch.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3:] = -Rt @ t
    out[..., 3, 3].fill_(1.0)
    return out


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """Unit-normalised ``quat_wxyz`` [..., 4] -> rotation [..., 3, 3]."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
