"""Rigid-body dynamics and RK4: known answers, equilibrium, signs, convergence order."""

import functools

import numpy as np
import pytest
import torch

from nanosysid import dynamics, so3
from nanosysid.models.physics import PhysicsStep
from nanosysid.vehicle import Vehicle

V = Vehicle()


def hover_state(n=1):
    x = torch.zeros(n, 13, dtype=torch.float64)
    x[:, 2] = 1.0
    x[:, 9] = 1.0
    return x


def test_mixer_signs_match_the_paper():
    kf, km, L = 2.0, 3.0, 0.5
    M = dynamics.mixer_matrix(k_f=kf, k_m=km, arm=L)
    expected = torch.tensor(
        [[kf, kf, kf, kf], [-kf * L, -kf * L, kf * L, kf * L], [-kf * L, kf * L, kf * L, -kf * L], [-km, km, -km, km]],
        dtype=torch.float64,
    )
    assert torch.equal(M, expected)


@pytest.mark.parametrize(
    "rotor, signs",
    [
        # M1 front-right (+x, -y), M2 rear-right, M3 rear-left, M4 front-left;
        # M2 and M4 spin clockwise seen from above, so their drag yaws the body +z.
        (0, (-1, -1, -1)),
        (1, (-1, +1, +1)),
        (2, (+1, +1, -1)),
        (3, (+1, -1, +1)),
    ],
)
def test_one_faster_rotor_torques_as_its_position_says(rotor, signs):
    u = torch.full((4,), V.hover_speed, dtype=torch.float64)
    u[rotor] += 100.0
    _, tau = dynamics.rotor_wrench(u, k_f=V.k_f, k_m=V.k_m, arm=V.arm)
    assert tuple(int(s) for s in torch.sign(tau)) == signs
    # torque = r x F for a rotor at (+-L, +-L): the lever arm is L on each axis
    dF = V.k_f * ((V.hover_speed + 100) ** 2 - V.hover_speed**2)
    assert torch.allclose(tau[:2].abs(), torch.tensor([dF * V.arm] * 2, dtype=torch.float64))


def test_hover_is_an_equilibrium():
    x = hover_state(3)
    u = torch.full((3, 4), V.hover_speed, dtype=torch.float64)
    assert np.isclose(4 * V.k_f * V.hover_speed**2, V.mass * V.gravity)
    step = PhysicsStep(V, angular_dynamics=True, substeps=2)
    y = x
    for _ in range(500):  # 5 s
        y = step(y, u)
    assert torch.allclose(y, x, atol=1e-10)


def test_free_fall_and_tilted_thrust_known_answers():
    f = functools.partial(dynamics.quad_dynamics, **V.dynamics_kwargs())
    x = hover_state()
    dx = f(x, torch.zeros(1, 4, dtype=torch.float64))
    assert torch.allclose(dx[0, 3:6], torch.tensor([0, 0, -V.gravity], dtype=torch.float64))
    # rolled by +90 deg about x: body z points to world -y, thrust accelerates towards -y
    x[:, 6:10] = so3.quat_exp(torch.tensor([[np.pi / 2, 0, 0]], dtype=torch.float64))
    u = torch.full((1, 4), V.hover_speed, dtype=torch.float64)
    dx = f(x, u)
    assert torch.allclose(dx[0, 3:6], torch.tensor([0, -V.gravity, -V.gravity], dtype=torch.float64))


def test_gyroscopic_coupling_and_zero_angular_acceleration_option():
    f = functools.partial(dynamics.quad_dynamics, **V.dynamics_kwargs())
    x = hover_state()
    x[:, 10:13] = torch.tensor([3.0, 2.0, 1.0], dtype=torch.float64)
    u = torch.full((1, 4), V.hover_speed, dtype=torch.float64)
    J = torch.tensor(V.inertia, dtype=torch.float64)
    w = x[0, 10:13]
    assert torch.allclose(f(x, u)[0, 10:], -torch.linalg.cross(w, J * w) / J)
    g = functools.partial(dynamics.quad_dynamics, **V.dynamics_kwargs(), angular_dynamics=False)
    assert torch.equal(g(x, u)[0, 10:], torch.zeros(3, dtype=torch.float64))
    # the quaternion kinematics are the same either way
    assert torch.equal(g(x, u)[0, :10], f(x, u)[0, :10])


def test_torque_equation_about_chosen_axes_only():
    # at hover speed with w = (3, 2, 1) rad/s the rotors' torques cancel, so dw/dt is the
    # gyroscopic term alone, worked out by hand: -(w x Jw) / J, component by component; the
    # discovered model keeps it about the axes it integrates and holds w about the others
    from nanosysid.discover.model import AugmentedStep

    step = AugmentedStep(V, ["drag_moment"], [1e-4], integrated=(True, False, True))
    x = hover_state()
    x[:, 10:13] = torch.tensor([3.0, 2.0, 1.0], dtype=torch.float64)
    u = torch.cat([torch.full((1, 4), V.hover_speed, dtype=torch.float64), torch.zeros(1, 4, dtype=torch.float64)], -1)
    jx, jy, jz = V.inertia
    hand = [-(2.0 * jz * 1.0 - 1.0 * jy * 2.0) / jx, 0.0, -(3.0 * jy * 2.0 - 2.0 * jx * 3.0) / jz]
    assert np.allclose(step._dx(x, u)[0, 10:].numpy(), hand, rtol=1e-12, atol=0)
    # an extra torque moves only the integrated axes; the translation and attitude are untouched
    full = AugmentedStep(V, ["drag_moment"], [1e-4])
    tau = torch.cat([u, torch.tensor([[0.0, 0.0, 0.0, 1e-4, 1e-4, 1e-4]], dtype=torch.float64)], -1)
    d = (step._dx(x, tau) - step._dx(x, u))[0, 10:].numpy()
    assert np.allclose(d, [1e-4 / jx, 0.0, 1e-4 / jz], rtol=1e-9, atol=0)
    assert torch.equal(step._dx(x, u)[0, :10], full._dx(x, u)[0, :10])
    with pytest.raises(ValueError, match="one flag per body axis"):
        AugmentedStep(V, integrated=(True, False))


def test_rk4_fourth_order_on_attitude_kinematics():
    """Constant body rate: q(t) = q0 ⊗ exp(w t) exactly; RK4 error must scale as dt^4."""
    w = torch.tensor([[2.0, -1.0, 3.0]], dtype=torch.float64)
    q0 = so3.quat_exp(torch.tensor([[0.3, 0.2, -0.1]], dtype=torch.float64))

    def f(q, _):
        return 0.5 * so3.quat_mul(q, torch.cat((w, torch.zeros(1, 1, dtype=torch.float64)), -1))

    t_end = 1.0
    exact = so3.quat_mul(q0, so3.quat_exp(w * t_end))
    errs = []
    for n in (10, 20, 40, 80):
        q = q0
        for _ in range(n):
            q = dynamics.rk4_step(f, q, None, t_end / n)
        errs.append((q - exact).norm().item())
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(np.abs(orders - 4) < 0.3), orders


def test_rk4_order_on_full_dynamics_against_fine_reference():
    """Convergence order of the physics step on a generic tumbling flight."""
    rng = np.random.default_rng(0)
    x0 = hover_state()
    x0[:, 3:6] = torch.from_numpy(rng.normal(size=(1, 3)))
    x0[:, 10:13] = torch.from_numpy(rng.normal(size=(1, 3)) * 2)
    u = torch.from_numpy(V.hover_speed + rng.normal(size=(1, 4)) * 100)

    def run(substeps):
        step = PhysicsStep(V, dt=0.05, substeps=substeps, angular_dynamics=True)
        step.forward = functools.partial(_raw_step, step)  # no renormalisation: pure RK4
        return step(x0, u)

    ref = run(512)
    errs = [(run(n) - ref).norm().item() for n in (2, 4, 8)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 3.6), orders


def _raw_step(self, y, u):
    h = self.dt / self.substeps
    for _ in range(self.substeps):
        y = dynamics.rk4_step(self._f, y, u, h)
    return y


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("angular", [False, True])
def test_dynamics_batched_equals_unbatched(dtype, angular):
    rng = np.random.default_rng(1)
    x = hover_state(12).to(dtype)
    x[:, :6] = torch.from_numpy(rng.normal(size=(12, 6))).to(dtype)
    x[:, 6:10] = so3.quat_exp(torch.from_numpy(rng.normal(size=(12, 3)))).to(dtype)
    x[:, 10:] = torch.from_numpy(rng.normal(size=(12, 3))).to(dtype)
    u = torch.from_numpy(V.hover_speed + rng.normal(size=(12, 4)) * 50).to(dtype)
    step = PhysicsStep(V, angular_dynamics=angular)
    batched = step(x.reshape(3, 4, 13), u.reshape(3, 4, 4)).reshape(12, 13)
    single = torch.stack([step(x[i], u[i]) for i in range(12)])
    assert batched.dtype == dtype
    assert torch.allclose(batched, single, atol=1e-5 if dtype == torch.float32 else 1e-12)
