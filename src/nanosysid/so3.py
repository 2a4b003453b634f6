"""Unit quaternions and rotation vectors, batched over leading dimensions.

Convention (the benchmark paper's): Hamilton product, scalar-last ``xyzw``. A quaternion
``q`` maps body-frame vectors to the world frame, ``v_W = R(q) v_B``. Every function takes
torch tensors of shape ``(..., 4)`` or ``(..., 3)``, works in float32 and float64, and
has no per-sample Python loop.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "quat_mul",
    "quat_conj",
    "quat_normalize",
    "quat_canonical",
    "quat_to_rotmat",
    "rotmat_to_quat",
    "quat_rotate",
    "quat_log",
    "quat_exp",
    "geodesic_angle",
    "skew",
]

# Below this angle (rad) the series expansions replace the closed forms, whose
# ratios become 0/0. Chosen so both branches agree to machine precision in float64.
_SMALL_ANGLE = 1e-4


def quat_mul(q1: Tensor, q2: Tensor) -> Tensor:
    """Hamilton product ``q1 ⊗ q2`` of ``xyzw`` quaternions, broadcast over ``...``."""
    x1, y1, z1, w1 = q1.unbind(-1)
    x2, y2, z2, w2 = q2.unbind(-1)
    return torch.stack(
        (
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ),
        dim=-1,
    )


def quat_conj(q: Tensor) -> Tensor:
    """Conjugate, which is the inverse for a unit quaternion."""
    return torch.cat((-q[..., :3], q[..., 3:]), dim=-1)


def quat_normalize(q: Tensor) -> Tensor:
    """Project onto the unit sphere."""
    return q / q.norm(dim=-1, keepdim=True)


def quat_canonical(q: Tensor) -> Tensor:
    """Pick the representative with ``w >= 0`` (``q`` and ``-q`` are the same rotation)."""
    return torch.where(q[..., 3:] < 0, -q, q)


def skew(v: Tensor) -> Tensor:
    """Cross-product matrix ``[v]x`` of shape ``(..., 3, 3)``."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack(
        (torch.stack((o, -z, y), -1), torch.stack((z, o, -x), -1), torch.stack((-y, x, o), -1)),
        dim=-2,
    )


def quat_to_rotmat(q: Tensor) -> Tensor:
    """Rotation matrix ``R(q)`` of shape ``(..., 3, 3)`` (body to world)."""
    x, y, z, w = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    row0 = torch.stack((1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)), -1)
    row1 = torch.stack((2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)), -1)
    row2 = torch.stack((2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)), -1)
    return torch.stack((row0, row1, row2), dim=-2)


def rotmat_to_quat(R: Tensor) -> Tensor:
    """Quaternion (``w >= 0``) of a rotation matrix ``(..., 3, 3)``.

    Shepperd's method: of the four algebraically equivalent formulas, use the one whose
    divisor is largest, so the result is accurate for every rotation.
    """
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # (..., 4): 4*w^2, 4*x^2, 4*y^2, 4*z^2 up to the common "1 +"
    diag = torch.stack(
        (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), -1
    )
    k = diag.argmax(dim=-1, keepdim=True)
    s = 2 * diag.gather(-1, k).clamp_min(1e-30).sqrt()  # (..., 1) = 4 * largest component
    r21_12, r02_20, r10_01 = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    r10p01, r02p20, r21p12 = R[..., 1, 0] + R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] + R[..., 1, 2]
    s = s.squeeze(-1)
    cand = torch.stack(
        (
            torch.stack((r21_12 / s, r02_20 / s, r10_01 / s, s / 4), -1),  # w largest
            torch.stack((s / 4, r10p01 / s, r02p20 / s, r21_12 / s), -1),  # x largest
            torch.stack((r10p01 / s, s / 4, r21p12 / s, r02_20 / s), -1),  # y largest
            torch.stack((r02p20 / s, r21p12 / s, s / 4, r10_01 / s), -1),  # z largest
        ),
        dim=-2,
    )  # (..., 4 candidates, 4)
    q = cand.gather(-2, k.unsqueeze(-1).expand(*k.shape[:-1], 1, 4)).squeeze(-2)
    return quat_canonical(quat_normalize(q))


def quat_rotate(q: Tensor, v: Tensor) -> Tensor:
    """Rotate body-frame vectors ``v (..., 3)`` into the world frame."""
    qv, w = q[..., :3], q[..., 3:]
    t = 2 * torch.linalg.cross(qv, v, dim=-1)
    return v + w * t + torch.linalg.cross(qv, t, dim=-1)


def quat_log(q: Tensor) -> Tensor:
    """Rotation vector ``r = angle * axis`` of a unit quaternion, with ``|r| <= pi``.

    The paper's equation (quat_to_so3), evaluated on the ``w >= 0`` representative so the
    angle stays in ``[0, pi]``; near zero angle a series replaces ``angle / |q_v|``.
    """
    q = quat_canonical(q)
    qv, w = q[..., :3], q[..., 3]
    n = qv.norm(dim=-1)
    angle = 2 * torch.atan2(n, w)
    small = n < _SMALL_ANGLE / 2
    n_safe = torch.where(small, torch.ones_like(n), n)
    w_safe = torch.where(small, w, torch.ones_like(w))
    # angle / n = 2/w * (1 - n^2 / (3 w^2) + ...) for small n
    scale = torch.where(small, 2 / w_safe * (1 - n * n / (3 * w_safe * w_safe)), angle / n_safe)
    return qv * scale.unsqueeze(-1)


def quat_exp(r: Tensor) -> Tensor:
    """Unit quaternion (``xyzw``) of a rotation vector ``r (..., 3)``."""
    theta = r.norm(dim=-1)
    small = theta < _SMALL_ANGLE
    t_safe = torch.where(small, torch.ones_like(theta), theta)
    t2 = theta * theta
    # sin(theta/2) / theta = 1/2 - theta^2/48 + ... for small theta
    k = torch.where(small, 0.5 - t2 / 48, torch.sin(t_safe / 2) / t_safe)
    return torch.cat((r * k.unsqueeze(-1), torch.cos(theta / 2).unsqueeze(-1)), dim=-1)


def geodesic_angle(q_true: Tensor, q_pred: Tensor) -> Tensor:
    """Geodesic distance on SO(3) in rad, in ``[0, pi]``.

    The paper's ``2 atan2(|q_v|, q_w)`` of ``q_rel = q_true^-1 ⊗ q_pred``, taken with
    ``|q_w|`` so that ``q`` and ``-q`` (the same rotation) give the same error.
    """
    rel = quat_mul(quat_conj(q_true), q_pred)
    return 2 * torch.atan2(rel[..., :3].norm(dim=-1), rel[..., 3].abs())
