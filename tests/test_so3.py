"""Quaternion algebra: identities, known answers, batching, both float precisions."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from nanosysid import so3

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
quat_arrays = arrays(np.float64, (4,), elements=finite).filter(lambda q: np.linalg.norm(q) > 0.1)
rotvecs = arrays(np.float64, (3,), elements=st.floats(-3.0, 3.0)).filter(lambda r: np.linalg.norm(r) < math.pi - 1e-3)


def unit(q):
    q = torch.as_tensor(q, dtype=torch.float64)
    return q / q.norm()


@settings(max_examples=200, deadline=None)
@given(quat_arrays)
def test_exp_log_is_identity_up_to_sign(q):
    q = unit(q)
    back = so3.quat_exp(so3.quat_log(q))
    assert min((back - q).abs().max(), (back + q).abs().max()) < 1e-12


@settings(max_examples=200, deadline=None)
@given(rotvecs)
def test_log_exp_is_identity(r):
    r = torch.as_tensor(r)
    assert torch.allclose(so3.quat_log(so3.quat_exp(r)), r, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(quat_arrays, quat_arrays)
def test_geodesic_symmetric_and_sign_invariant(a, b):
    qa, qb = unit(a), unit(b)
    d = so3.geodesic_angle(qa, qb)
    assert torch.allclose(d, so3.geodesic_angle(qb, qa), atol=1e-12)
    assert torch.allclose(d, so3.geodesic_angle(qa, -qb), atol=1e-12)
    assert 0 <= d <= math.pi + 1e-12


@settings(max_examples=200, deadline=None)
@given(quat_arrays, rotvecs)
def test_geodesic_equals_rotation_angle(a, r):
    q = unit(a)
    r = torch.as_tensor(r)
    rotated = so3.quat_mul(q, so3.quat_exp(r))
    assert torch.allclose(so3.geodesic_angle(q, rotated), r.norm(), atol=1e-9)


def test_products_and_matrices_match_scipy(rng):
    q1, q2 = Rotation.random(50, random_state=1), Rotation.random(50, random_state=2)
    t1, t2 = torch.from_numpy(q1.as_quat()), torch.from_numpy(q2.as_quat())  # scipy is xyzw too
    prod = so3.quat_mul(t1, t2).numpy()
    ref = (q1 * q2).as_quat()
    assert np.allclose(np.abs(np.sum(prod * ref, axis=1)), 1.0, atol=1e-12)
    assert np.allclose(so3.quat_to_rotmat(t1).numpy(), q1.as_matrix(), atol=1e-12)
    v = rng.normal(size=(50, 3))
    assert np.allclose(so3.quat_rotate(t1, torch.from_numpy(v)).numpy(), q1.apply(v), atol=1e-12)
    assert np.allclose(so3.quat_log(t1).numpy(), Rotation.from_quat(so3.quat_canonical(t1).numpy()).as_rotvec(), atol=1e-12)
    back = so3.rotmat_to_quat(torch.from_numpy(q1.as_matrix()))
    assert torch.allclose(so3.geodesic_angle(back, t1), torch.zeros(50, dtype=torch.float64), atol=1e-7)


def test_conjugate_is_inverse():
    q = torch.from_numpy(Rotation.random(20, random_state=3).as_quat())
    ident = so3.quat_mul(q, so3.quat_conj(q))
    assert torch.allclose(ident, torch.tensor([0.0, 0, 0, 1], dtype=torch.float64).expand(20, 4), atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-6, 1e-4, 1e-2, math.pi - 1e-6, math.pi])
def test_log_exp_near_zero_and_pi(angle):
    axis = torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64)
    axis = axis / axis.norm()
    r = axis * angle
    q = so3.quat_exp(r)
    assert abs(q.norm() - 1) < 1e-14
    back = so3.quat_log(q)
    # at exactly pi, r and -r are the same rotation
    assert torch.allclose(back, r, atol=1e-10) or (angle == math.pi and torch.allclose(back, -r, atol=1e-10))
    assert abs(so3.geodesic_angle(torch.tensor([0.0, 0, 0, 1], dtype=torch.float64), q) - angle) < 1e-9


def test_gradients_finite_at_zero_angle():
    r = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    so3.quat_exp(r).sum().backward()
    assert torch.isfinite(r.grad).all()
    q = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64, requires_grad=True)
    so3.quat_log(q).sum().backward()
    assert torch.isfinite(q.grad).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_batched_equals_unbatched(dtype):
    q = torch.from_numpy(Rotation.random(24, random_state=4).as_quat()).to(dtype)
    p = torch.from_numpy(Rotation.random(24, random_state=5).as_quat()).to(dtype)
    qb, pb = q.reshape(2, 3, 4, 4), p.reshape(2, 3, 4, 4)
    fns = [
        lambda a, b: so3.quat_mul(a, b),
        lambda a, b: so3.geodesic_angle(a, b),
        lambda a, b: so3.quat_log(a),
        lambda a, b: so3.quat_exp(so3.quat_log(b)),
        lambda a, b: so3.quat_to_rotmat(a),
    ]
    tol = 1e-6 if dtype == torch.float32 else 1e-13
    for fn in fns:
        batched = fn(qb, pb)
        assert batched.dtype == dtype
        single = torch.stack([fn(q[i], p[i]) for i in range(24)])
        assert torch.allclose(batched.reshape(single.shape), single, atol=tol)
