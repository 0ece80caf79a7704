"""SE(3) maths: exp/log round trips, inverses, quaternions, and gradients at the identity."""

from __future__ import annotations

import torch

from bench.slam.se3 import hat, inverse, quat_to_rotmat, rotmat_to_quat, se3_exp, se3_log, so3_exp, so3_log


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
