"""SE(3) maths: exp/log round trips, inverses, quaternions, and gradients at the identity."""

from __future__ import annotations

import torch

from bench.slam.se3 import _SMALL, _coeffs, hat, inverse, quat_to_rotmat, se3_exp, so3_exp, so3_log


# the inverses of se3_exp and quat_to_rotmat: only these tests need them, so they live here, not in bench
def se3_log(T: torch.Tensor) -> torch.Tensor:
    """Pose [..., 4, 4] -> twist [..., 6]."""
    R, t = T[..., :3, :3], T[..., :3, 3]
    w = so3_log(R)
    theta2 = (w * w).sum(-1)[..., None, None]
    a, b, _ = _coeffs(theta2)
    W = hat(w)
    eye = torch.eye(3, dtype=T.dtype, device=T.device).expand(W.shape)
    # V^-1 = I - W/2 + (1/theta^2)(1 - a/(2b)) W^2
    small = theta2 < _SMALL
    coef = torch.where(small, torch.full_like(theta2, 1 / 12), (1 - a / (2 * b)) / torch.where(small, 1, theta2))
    V_inv = eye - 0.5 * W + coef * (W @ W)
    v = (V_inv @ t[..., None])[..., 0]
    return torch.cat([v, w], -1)


def rotmat_to_quat(R: torch.Tensor) -> torch.Tensor:
    """Rotation [..., 3, 3] -> ``quat_wxyz`` [..., 4] with w >= 0 (Shepperd's method)."""
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cands = torch.stack(
        [
            torch.stack(
                [1 + tr, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            torch.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
                ],
                -1,
            ),
        ],
        -2,
    )  # [..., 4, 4]; row k is 4*q*q_k, best conditioned where its own entry is largest
    diag = torch.stack(
        [
            1 + tr,
            1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
        ],
        -1,
    )
    best = diag.argmax(-1)
    q = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4))[..., 0, :]
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def test_exp_log_round_trip():
    xi = torch.randn(64, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    xi[:, 3:] *= 0.9  # rotation angles below pi
    torch.testing.assert_close(se3_log(se3_exp(xi)), xi)
    torch.testing.assert_close(so3_log(so3_exp(xi[:, 3:])), xi[:, 3:])


def test_exp_is_a_rigid_motion_and_matches_matrix_exponential():
    xi = torch.tensor([0.3, -0.2, 0.5, 0.1, 0.4, -0.3], dtype=torch.float64)
    T = se3_exp(xi)
    R = T[:3, :3]
    torch.testing.assert_close(R.T @ R, torch.eye(3, dtype=torch.float64))
    assert torch.det(R) > 0
    twist = torch.zeros(4, 4, dtype=torch.float64)
    twist[:3, :3] = hat(xi[3:])
    twist[:3, 3] = xi[:3]
    torch.testing.assert_close(T, torch.linalg.matrix_exp(twist))


def test_inverse_and_quaternions():
    T = se3_exp(torch.randn(10, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(1)))
    torch.testing.assert_close(inverse(T) @ T, torch.eye(4, dtype=torch.float64).expand(10, 4, 4))
    q = rotmat_to_quat(T[:, :3, :3])
    assert (q[:, 0] >= 0).all()
    torch.testing.assert_close(q.norm(dim=-1), torch.ones(10, dtype=torch.float64))
    torch.testing.assert_close(quat_to_rotmat(q), T[:, :3, :3])
    # a known rotation: 90 degrees about z
    Rz = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)
    s = 0.5**0.5
    torch.testing.assert_close(rotmat_to_quat(Rz), torch.tensor([s, 0, 0, s], dtype=torch.float64))


def test_gradient_at_identity_is_finite_and_correct():
    xi = torch.zeros(6, dtype=torch.float64, requires_grad=True)
    p = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    (se3_exp(xi)[:3, :3] @ p + se3_exp(xi)[:3, 3]).sum().backward()
    # R p + t ~ p + w x p + v, so d/dxi of its sum is 1 for v and d/dw[w . (p x 1)] = p x 1 for w
    expected = torch.ones(6, dtype=torch.float64)
    expected[3:] = torch.linalg.cross(p, torch.ones(3, dtype=torch.float64))
    torch.testing.assert_close(xi.grad, expected)
